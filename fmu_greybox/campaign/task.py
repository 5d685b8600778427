"""One recording of a campaign, diagnosed as a task on a Dask worker.

The task receives the project, the SHA-256 of the white-box FMU that
:class:`~fmu_greybox.campaign.cluster.FmuOnWorkers` put on the worker, and the recording's
arrays; it runs the whole diagnosis in the worker process (its hypothesis simulations in that
process too: the cluster's parallelism is across recordings) and returns what the client writes:
``diagnosis.json``'s payload and the HTML report. Workers write nothing of their own, so they
need no file system shared with the client.
"""

from __future__ import annotations

import dataclasses
import time

from distributed import get_worker

from fmu_greybox.campaign.cluster import fmu_file, worker_stats
from fmu_greybox.data.recording import Recording
from fmu_greybox.diagnosis.diagnose import Diagnosis, GreyBoxSettings
from fmu_greybox.diagnosis.report import diagnosis_payload, report_html
from fmu_greybox.project.config import ProjectConfig


@dataclasses.dataclass(frozen=True)
class RecordingTask:
    """What every task of a campaign shares.

    Attributes
    ----------
    config : ProjectConfig
        The project as the client read it.
    fmu_sha256 : str
        The white-box FMU on the workers.
    fmu_name : str
        The FMU's path on the client (what ``diagnosis.json`` names).
    greybox : bool
        Train the grey-box on the named terms in each diagnosis.
    """

    config: ProjectConfig
    fmu_sha256: str
    fmu_name: str
    greybox: bool = True

    def __call__(self, recording: Recording) -> dict:
        """Diagnose one recording on this worker.

        Returns
        -------
        dict
            ``payload`` (``diagnosis.json``), ``html`` (the report), ``seconds``, ``worker``
            (its address) and ``peak_rss`` (the worker process' peak memory so far [bytes]).
        """
        started = time.perf_counter()
        config = dataclasses.replace(self.config, fmu=str(fmu_file(self.fmu_sha256)))
        settings = GreyBoxSettings() if self.greybox else None
        diagnosis = Diagnosis(config, workers=1, greybox=settings).fit(recording)
        payload = diagnosis_payload(diagnosis, recording)
        payload["fmu"] = self.fmu_name
        return {
            "payload": payload,
            "html": report_html(diagnosis, payload),
            "seconds": round(time.perf_counter() - started, 2),
            "worker": get_worker().address,
            "peak_rss": worker_stats()["peak_rss"],
        }
