"""A campaign: many recordings of one project, each diagnosed as a task on a Dask cluster.

The client reads each recording (it holds the files), hashes it and skips it when
``DIR/recordings/NAME-SHA/diagnosis.json`` already holds its diagnosis for the same recording
SHA-256, tool version and campaign key (project, FMU, settings). The others are scattered to
the workers and submitted, at most :func:`in_flight` at a time, so that a campaign of thousands
of recordings holds only a few of them in memory anywhere. Results are written as they arrive
(each recording's ``diagnosis.json`` and ``report.html``, atomically) and reported to a
progress callback; a recording that fails, to load or to diagnose, is reported with its error
and the others go on. At the end ``campaign.json`` and ``campaign.html`` are written.
"""

from __future__ import annotations

import hashlib
import json
import re
import time
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from distributed import Client, as_completed

from fmu_greybox import __version__
from fmu_greybox.campaign.cluster import FmuBlob, FmuOnWorkers
from fmu_greybox.campaign.page import write_page
from fmu_greybox.campaign.task import RecordingTask
from fmu_greybox.campaign.trends import DRIFT_ALPHA, campaign_trends, magnitude_problem
from fmu_greybox.data.recording import Recording
from fmu_greybox.diagnosis.report import write_json, write_report_files
from fmu_greybox.errors import DiagnosisFormatError, FmuGreyboxError
from fmu_greybox.project.config import ProjectConfig
from fmu_greybox.project.data import load_project_recording, whitebox_path
from fmu_greybox.project.fingerprint import (
    COPY_SHARE,
    RowFingerprint,
    copy_message,
    fingerprint,
    recorded_rows,
    shared_rows,
)

SCHEMA_VERSION = 1
TOOL = f"fmu-greybox {__version__}"
#: Folder of the per-recording results, inside the campaign folder.
RECORDINGS = "recordings"


@dataclass
class RecordingOutcome:
    """One recording of a campaign, as ``campaign.json`` lists it.

    Attributes
    ----------
    index : int
        Position on the command line.
    source : str
        The file.
    sha256 : str or None
        :meth:`Recording.sha256` (``None`` if it could not be read).
    start_time : str or None
        The recording's start time where the file carries one (``metadata["time_origin"]``).
    status : str
        ``diagnosed``, ``reused`` (an earlier run's diagnosis) or ``failed``.
    folder : str or None
        Its results, relative to the campaign folder.
    payload : dict or None
        Its ``diagnosis.json``.
    error : str or None
        Why it failed.
    seconds : float or None
        Time of its diagnosis on the worker.
    worker : str or None
        Address of the worker that diagnosed it.
    """

    index: int
    source: str
    sha256: str | None = None
    start_time: str | None = None
    status: str = "failed"
    folder: str | None = None
    payload: dict | None = None
    error: str | None = None
    seconds: float | None = None
    worker: str | None = None

    def to_dict(self) -> dict:
        found = self.payload is not None
        return {
            "index": self.index,
            "source": self.source,
            "sha256": self.sha256,
            "start_time": self.start_time,
            "status": self.status,
            "verdict": self.payload["verdict"] if found else None,
            "origin_stage": self.payload["origin_stage"] if found else None,
            "findings": self.payload["findings"] if found else None,
            "report": f"{self.folder}/report.html" if found else None,
            "diagnosis": f"{self.folder}/diagnosis.json" if found else None,
            "error": self.error,
            "seconds": self.seconds,
            "worker": self.worker,
        }

    def line(self) -> str:
        """One line saying how it ended."""
        name = Path(self.source).name
        if self.status == "failed":
            return f"{name}: FAILED: {self.error}"
        named = [
            f"{f['effect']} {f['magnitude']['value']:.4g} {f['magnitude']['unit']} [{f['stage']}]"
            for f in self.payload["findings"]
            if f["effect"] not in ("none", "unexplained")
        ]
        verdict = ", ".join(named) or self.payload["findings"][0]["effect"]
        took = f" in {self.seconds:.1f} s" if self.status == "diagnosed" else ""
        return f"{name}: {self.status}{took}: {verdict}"


Progress = Callable[[RecordingOutcome, int, int], None]


def campaign_key(config: ProjectConfig, fmu: FmuBlob, greybox: bool) -> str:
    """SHA-256 of what a diagnosis depends on besides the recording: tool version, project,
    white-box FMU and settings. A rerun reuses a diagnosis only under the same key."""
    content = {
        "tool": TOOL,
        "project": config.to_dict(),
        "fmu_sha256": fmu.sha256,
        "greybox": greybox,
    }
    text = json.dumps(content, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def folder_name(source: str, sha256: str) -> str:
    """``STEM-SHA12``: readable, and unique per recording content."""
    stem = re.sub(r"[^A-Za-z0-9_.-]+", "_", Path(source).stem) or "recording"
    return f"{stem}-{sha256[:12]}"


def earlier_diagnoses(out_dir: Path) -> dict[str, list[Path]]:
    """The ``diagnosis.json`` files of an earlier run, by the first 12 digits of their
    recording's SHA-256 (read from the folder names once, not per recording)."""
    found: dict[str, list[Path]] = {}
    for path in sorted((out_dir / RECORDINGS).glob("*-*/diagnosis.json")):
        found.setdefault(path.parent.name.rsplit("-", 1)[1], []).append(path)
    return found


def reusable(earlier: dict[str, list[Path]], sha256: str, key: str) -> tuple[str, dict] | None:
    """An earlier diagnosis of this recording content under this key, if there is one.

    Parameters
    ----------
    earlier : dict
        :func:`earlier_diagnoses` of the campaign folder.
    sha256 : str
        The recording's :meth:`Recording.sha256`.
    key : str
        :func:`campaign_key` of this run.

    Returns
    -------
    (str, dict) or None
        Its folder (relative to the campaign folder) and its ``diagnosis.json``.
    """
    for path in earlier.get(sha256[:12], []):
        try:
            payload = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        same = payload.get("recording", {}).get("sha256") == sha256
        if same and payload.get("tool") == TOOL and payload.get("campaign_key") == key:
            return f"{RECORDINGS}/{path.parent.name}", payload
    return None


def check_reused(payload: dict, path: Path) -> None:
    """Refuse an earlier ``diagnosis.json`` holding what no diagnosis writes.

    A reused diagnosis is trended as it stands, so every magnitude must be a finite number
    inside its own 95 % interval (where it has one: finite and ordered), and the fields the
    campaign reads must be there.

    Parameters
    ----------
    payload : dict
        The file's content.
    path : Path
        The file (named in the error).

    Raises
    ------
    DiagnosisFormatError
        Naming the file, the finding and what is wrong, with the remedy.
    """

    def refuse(what: str) -> DiagnosisFormatError:
        return DiagnosisFormatError(
            f"{path}: {what}; no diagnosis writes that, so the file was damaged or edited and "
            "is not reused. Delete it (or its folder) and run the campaign again to diagnose "
            "the recording afresh"
        )

    findings = payload.get("findings")
    if not isinstance(findings, list) or not findings or "verdict" not in payload:
        raise refuse("it holds no 'verdict' and list of 'findings'")
    for number, finding in enumerate(findings, 1):
        if not isinstance(finding, dict) or not isinstance(finding.get("effect"), str):
            raise refuse(f"finding {number} is not an object with an 'effect'")
        where = f"finding {number} ({finding['effect']})"
        magnitudes = finding.get("magnitudes") or {}
        if not isinstance(magnitudes, dict) or (magnitudes and "hypothesis" not in finding):
            raise refuse(f"{where}: its 'magnitudes' are not an object under a 'hypothesis'")
        if finding["effect"] not in ("none", "unexplained"):
            magnitudes = {"magnitude": finding.get("magnitude"), **magnitudes}
        for name, magnitude in magnitudes.items():
            problem = magnitude_problem(magnitude)
            if problem is not None:
                raise refuse(f"{where}, magnitude {name!r}: {problem}")


def in_flight(client: Client) -> int:
    """Recordings submitted at a time: two per worker thread (one running, one queued)."""
    threads = sum(client.nthreads().values())
    return max(2, 2 * threads)


def run_campaign(
    config: ProjectConfig,
    recordings: Sequence[str | Path],
    out_dir: str | Path,
    client: Client,
    greybox: bool = True,
    progress: Progress | None = None,
) -> dict:
    """Diagnose every recording on the cluster of ``client``; write the campaign's files.

    Parameters
    ----------
    config : ProjectConfig
    recordings : sequence of path
        Recording files, in campaign order (unless they all carry a start time).
    out_dir : path
        Campaign folder (created if needed): ``campaign.json``, ``campaign.html`` and
        ``recordings/NAME-SHA/{diagnosis.json,report.html}``.
    client : distributed.Client
    greybox : bool
        Train the grey-box on the named terms in each diagnosis.
    progress : callable, optional
        Called as ``progress(outcome, done, total)`` each time a recording is finished.

    Returns
    -------
    dict
        The content of ``campaign.json``.
    """
    started = time.perf_counter()
    out = Path(out_dir)
    (out / RECORDINGS).mkdir(parents=True, exist_ok=True)
    fmu_path = whitebox_path(config)
    blob = FmuBlob.read(fmu_path)
    key = campaign_key(config, blob, greybox)
    task = RecordingTask(config, blob.sha256, str(fmu_path), greybox)
    outcomes = [RecordingOutcome(i, str(p)) for i, p in enumerate(recordings)]
    plugin = FmuOnWorkers(blob)
    client.register_plugin(plugin)
    try:
        _Submissions(client, task, out, key, progress).run(outcomes)
    finally:
        client.unregister_worker_plugin(plugin.name)
    payload = campaign_payload(config, str(fmu_path), blob, key, outcomes, client)
    payload["summary"]["wall_seconds"] = round(time.perf_counter() - started, 2)
    write_json(payload, out / "campaign.json")
    write_page(payload, out / "campaign.html")
    return payload


class _Submissions:
    """The recordings of one run on the cluster: read, reused or submitted, collected as they
    finish (at most :func:`in_flight` at a time), each reported once.

    Parameters
    ----------
    client : distributed.Client
    task : RecordingTask
    out : Path
        The campaign folder.
    key : str
        :func:`campaign_key` of this run.
    progress : callable or None
    """

    def __init__(
        self, client: Client, task: RecordingTask, out: Path, key: str, progress: Progress | None
    ) -> None:
        self.client, self.task, self.out, self.key = client, task, out, key
        self.progress = progress
        self.earlier = earlier_diagnoses(out)
        self.seen: list[tuple[str, list[str], RowFingerprint]] = []
        self.waiting: dict[str, RecordingOutcome] = {}
        self.done = 0
        self.total = 0

    def run(self, outcomes: list[RecordingOutcome]) -> None:
        """Fill every outcome in."""
        self.total = len(outcomes)
        running = as_completed()
        limit = in_flight(self.client)
        for outcome in outcomes:
            future = self.submit(outcome)
            if future is None:
                self.report(outcome)
                continue
            self.waiting[future.key] = outcome
            running.add(future)
            while running.count() >= limit:
                self.collect(next(running))
        for future in running:
            self.collect(future)

    def submit(self, outcome: RecordingOutcome):
        """Read a recording; reuse its earlier diagnosis, or submit it (its future; ``None``
        when it is done here)."""
        try:
            recording = load_project_recording(self.task.config, outcome.source)
        except FmuGreyboxError as exc:
            outcome.error = str(exc)
            return None
        outcome.sha256 = recording.sha256()
        outcome.start_time = recording.metadata.get("time_origin")
        copied = self.copied(outcome.source, recording)
        if copied is not None:
            outcome.error = copied
            return None
        found = reusable(self.earlier, outcome.sha256, self.key)
        if found is not None:
            folder, payload = found
            try:
                check_reused(payload, self.out / folder / "diagnosis.json")
            except DiagnosisFormatError as exc:
                outcome.error = str(exc)
                return None
            outcome.folder, outcome.payload, outcome.status = folder, payload, "reused"
            return None
        name = folder_name(outcome.source, outcome.sha256)
        outcome.folder = f"{RECORDINGS}/{name}"
        shipped = self.client.scatter(recording, hash=False)
        key = f"fmu-greybox-diagnose-{name}-{uuid.uuid4().hex[:8]}"
        return self.client.submit(self.task, shipped, key=key, pure=False)

    def copied(self, source: str, recording: Recording) -> str | None:
        """Why a recording is left out as a copy of one read before it (``None`` when it is
        not): a flight counts once in the trends, however many files hold it
        (:func:`~fmu_greybox.project.fingerprint.find_copy`)."""
        ((_, values),) = recorded_rows([recording])
        names = sorted(recording.signals)
        for original, columns, rows in self.seen:
            share = shared_rows(values, rows) if columns == names else 0.0
            if share > COPY_SHARE:
                return (
                    f"{copy_message(source, original, share)}; left out, so that the trends "
                    "count each recording once"
                )
        self.seen.append((source, names, fingerprint(values)))
        return None

    def collect(self, future) -> None:
        """Write a finished recording's results (or note its error) and report it."""
        outcome = self.waiting.pop(future.key)
        try:
            result = future.result()
        except Exception as exc:  # any error of one recording is reported; the others go on
            outcome.error = str(exc) if isinstance(exc, FmuGreyboxError) else repr(exc)
            outcome.folder = None
        else:
            payload = {**result["payload"], "campaign_key": self.key}
            write_report_files(payload, result["html"], self.out / outcome.folder)
            outcome.payload, outcome.status = payload, "diagnosed"
            outcome.seconds, outcome.worker = result["seconds"], result["worker"]
        future.release()
        self.report(outcome)

    def report(self, outcome: RecordingOutcome) -> None:
        """Count a finished recording and tell the progress callback."""
        self.done += 1
        if self.progress is not None:
            self.progress(outcome, self.done, self.total)


def campaign_order(outcomes: Sequence[RecordingOutcome]) -> tuple[list[RecordingOutcome], str]:
    """The recordings by start time when every one carries one, else in the order given.

    Returns
    -------
    (list of RecordingOutcome, str)
        The ordered recordings and ``"start_time"`` or ``"given"``.
    """
    if outcomes and all(o.start_time is not None for o in outcomes):
        return sorted(outcomes, key=lambda o: np.datetime64(o.start_time)), "start_time"
    return list(outcomes), "given"


def campaign_payload(
    config: ProjectConfig,
    fmu_name: str,
    fmu: FmuBlob,
    key: str,
    outcomes: Sequence[RecordingOutcome],
    client: Client,
) -> dict:
    """The content of ``campaign.json`` (schema in ``docs/campaign.md``)."""
    ordered, order = campaign_order(outcomes)
    trends = campaign_trends([o.payload["findings"] if o.payload else None for o in ordered])
    status = [o.status for o in ordered]
    return {
        "schema_version": SCHEMA_VERSION,
        "tool": TOOL,
        "project": config.name,
        "config": str(config.path) if config.path else None,
        "fmu": fmu_name,
        "fmu_sha256": fmu.sha256,
        "campaign_key": key,
        "cluster": {
            "scheduler": client.scheduler.address,
            "workers": len(client.nthreads()),
            "threads": sum(client.nthreads().values()),
        },
        "order": order,
        "drift_test": {
            "test": "chi-square test of constancy: weighted mean of the magnitudes with "
            "weights 1/sigma^2, sigma = (ci95 high - low) / 3.92; drift when p < alpha",
            "alpha": DRIFT_ALPHA,
            "slope": "weighted least-squares slope of magnitude on recording index",
        },
        "summary": {
            "recordings": len(ordered),
            "diagnosed": status.count("diagnosed"),
            "reused": status.count("reused"),
            "failed": status.count("failed"),
        },
        "recordings": [o.to_dict() for o in ordered],
        "trends": [t.to_dict() for t in trends],
    }
