"""Provoke every bad input of docs/robustness.md and print what the user gets, as Markdown.

Each row is produced by running the bad input through fmu-greybox now: the exception type and
its message (temporary folders cut from paths, long messages abbreviated with "…"). A row whose
outcome is not an exception says what was left on disk, as checked by the script. An exception
that is not one of fmu-greybox's own would show as ``RAW <type>``: none should.

The hostile archives are made with the helpers of the tests that cover them
(tests/test_fmu_archive.py, tests/test_robustness_archive.py).

Usage: ``.venv/bin/python benchmarks/robustness_table.py > table.md``.
"""

from __future__ import annotations

import _ctypes
import datetime
import json
import os
import pickle
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import tomllib
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

import test_fmu_archive as archive_tests  # noqa: E402
import test_robustness_archive as hostile_tests  # noqa: E402
import test_robustness_runs as runs_tests  # noqa: E402

from fmu_greybox.data.recording import Recording, load_recording, save_recording  # noqa: E402
from fmu_greybox.errors import FmuGreyboxError  # noqa: E402
from fmu_greybox.fmi.archive import open_fmu  # noqa: E402
from fmu_greybox.fmi.builtin import reference_fmus  # noqa: E402
from fmu_greybox.fmi.instance import FmuInstance  # noqa: E402
from fmu_greybox.model.simulate import simulate_recording  # noqa: E402
from fmu_greybox.model.store import (  # noqa: E402
    FORMAT_VERSION,
    MANIFEST,
    MANIFEST_HASH,
    TRAINING_ROWS,
    file_sha256,
    load_model,
    manifest_digest,
    save_model,
)
from fmu_greybox.project.config import load_config, parse_config  # noqa: E402
from fmu_greybox.project.data import load_project_recording  # noqa: E402
from fmu_greybox.synth.actuator import FlightTestProfile, SynthRequest, synthesise  # noqa: E402
from fmu_greybox.workflow.train import train_model  # noqa: E402
from fmu_greybox.workflow.validate import (  # noqa: E402
    check_project,
    validate_model,
    validate_recordings,
)

REFERENCE = ROOT / "bench_configs" / "hydraulic_actuator.toml"
WIDTH = 190


@dataclass
class Case:
    """One bad input: the table section, what it is, how to provoke it, the test covering it."""

    section: str
    what: str
    provoke: Callable[[], object]
    test: str


def outcome(case: Case, tmp: Path) -> tuple[str, str]:
    """(what the user gets, the message) for one case.

    ``provoke`` raises the error the user sees, or returns ``(gets, what is left)`` for a case
    whose outcome is the state of the disk.
    """
    try:
        result = case.provoke()
    except FmuGreyboxError as error:
        return f"`{type(error).__name__}`", tidy(str(error), tmp)
    except Exception as error:  # a gap: shown as such
        return f"RAW `{type(error).__name__}`", tidy(str(error), tmp)
    if isinstance(result, tuple):
        return result[0], tidy(result[1], tmp)
    return "no exception", tidy(repr(result), tmp)


def tidy(message: str, tmp: Path) -> str:
    """Cut temporary folders from paths, abbreviate, escape for a Markdown table."""
    message = (
        message.replace(f"'{tmp}/", "'/tmp/…/")
        .replace(f"{tmp}/", "")
        .replace(str(tmp), ".")
        .replace(f"{ROOT}/", "")
    )
    message = re.sub(r"/tmp/fmu_greybox_\w+/", "<extracted>/", message)
    message = " ".join(message.split())
    if len(message) > WIDTH:
        message = message[: WIDTH - 1].rstrip() + "…"
    return message.replace("|", "\\|").replace("`", "'")


# ---------------------------------------------------------------------------- FMU archives


def archive_cases(tmp: Path, whitebox: Path, saved: Path) -> list[Case]:
    outside = tmp / "outside" / "evil.txt"
    outside.parent.mkdir()
    known = "test_fmu_archive.py::test_hostile_or_broken_archive_is_refused"

    def hostile(kind: str) -> Callable[[], object]:
        name = re.sub(r"\W+", "_", kind) + ".fmu"
        return lambda: open_fmu(archive_tests.hostile(kind, whitebox, tmp / name, outside))

    cases = [
        Case("archive", f"FMU: {kind}", hostile(kind), known) for kind in archive_tests.PROBLEMS
    ]
    stored, patch, rewrite = (
        hostile_tests.stored,
        hostile_tests.patch_central,
        archive_tests.rewrite,
    )
    here = "test_robustness_archive.py::"

    def patched(name: str, data: bytes, **fields: int) -> Callable[[], object]:
        target = tmp / f"patched_{len(list(tmp.iterdir()))}.fmu"
        return lambda: open_fmu(
            patch(rewrite(whitebox, target, add=[(stored(name), data)]), name, **fields)
        )

    def many_parts() -> object:
        target = rewrite(
            whitebox,
            tmp / "parts.fmu",
            add=[(stored(f"resources/part{i}.bin"), b"x") for i in range(3)],
        )
        for i in range(3):
            patch(target, f"resources/part{i}.bin", compress_size=2**30 - 1, file_size=2**30 - 1)
        return open_fmu(target)

    def lying() -> object:
        info = zipfile.ZipInfo("resources/lie.bin")
        info.compress_type = zipfile.ZIP_DEFLATED
        target = rewrite(whitebox, tmp / "lie.fmu", add=[(info, bytes(range(256)) * 200)])
        return open_fmu(patch(target, "resources/lie.bin", file_size=100))

    def duplicate() -> object:
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            target = rewrite(
                whitebox,
                tmp / "twice.fmu",
                add=[(zipfile.ZipInfo("modelDescription.xml"), b"<x/>")],
            )
        return open_fmu(target)

    def folder() -> object:
        (tmp / "unpacked.fmu").mkdir()
        return open_fmu(tmp / "unpacked.fmu")

    def empty() -> object:
        (tmp / "empty.fmu").write_bytes(b"")
        return open_fmu(tmp / "empty.fmu")

    def xml_entity(kind: str) -> Callable[[], object]:
        def make() -> object:
            xml = archive_tests.description(whitebox)
            if kind == "external":
                doctype, use = (
                    b'<!DOCTYPE x [<!ENTITY leak SYSTEM "file:///etc/hostname">]>',
                    b"&leak;",
                )
            else:
                levels = "".join(f'<!ENTITY e{i} "{f"&e{i - 1};" * 10}">' for i in range(1, 10))
                doctype, use = f'<!DOCTYPE x [<!ENTITY e0 "lol">{levels}]>'.encode(), b"&e9;"
            target = rewrite(
                whitebox,
                tmp / f"{kind}.fmu",
                replace={"modelDescription.xml": hostile_tests.with_doctype(xml, doctype, use)},
            )
            return open_fmu(target)

        return make

    def binary(content: bytes, name: str) -> Callable[[], object]:
        def make() -> object:
            target = rewrite(whitebox, tmp / name, replace={hostile_tests.LIBRARY: content})
            with open_fmu(target) as archive:
                return FmuInstance(archive, [], ["ram_position"])

        return make

    def foreign_guid() -> object:
        xml = archive_tests.description(whitebox)
        start = xml.index(b'guid="{') + 7
        target = rewrite(
            whitebox,
            tmp / "guid.fmu",
            replace={"modelDescription.xml": xml[:start] + b"00000000" + xml[start + 8 :]},
        )
        with open_fmu(target) as archive:
            return FmuInstance(archive, [], ["ram_position"])

    def misspelled_variable() -> object:
        with open_fmu(whitebox) as archive:
            return archive.variable("ram_positon")

    def without_slave_module() -> object:
        from fmu_greybox.export.fmu import export_greybox

        python_fmu = export_greybox(saved, tmp / "python.fmu", runtime="python").path
        slave_module = "resources/slavemodule.txt"
        target = rewrite(python_fmu, tmp / "incomplete.fmu", drop=lambda n: n == slave_module)
        return open_fmu(target)

    cases += [
        Case(
            "archive",
            "FMU: member declaring 4 GiB uncompressed",
            patched("resources/huge.bin", b"x", compress_size=0xFFFFFFF0, file_size=0xFFFFFFF0),
            here + "test_absurd_declared_member_size_is_refused_before_extraction",
        ),
        Case(
            "archive",
            "FMU: members declaring 3 GiB in all",
            many_parts,
            here + "test_total_declared_size_is_capped",
        ),
        Case(
            "archive",
            "FMU: member declaring bytes it does not hold",
            patched("resources/e.bin", b"", file_size=50_000),
            here + "test_declared_size_without_compressed_bytes_is_a_zip_bomb",
        ),
        Case(
            "archive",
            "FMU: member holding more than it declares",
            lying,
            here + "test_member_larger_than_declared_is_cut_at_its_declared_size",
        ),
        Case(
            "archive",
            "FMU: encrypted member",
            patched("resources/m.bin", b"z" * 99, flags=1),
            here + "test_encrypted_or_non_fmi_compression_is_refused",
        ),
        Case(
            "archive",
            "FMU: bzip2-compressed member",
            patched("resources/m.bin", b"z" * 99, method=12),
            here + "test_encrypted_or_non_fmi_compression_is_refused",
        ),
        Case(
            "archive",
            "FMU: member stored twice",
            duplicate,
            here + "test_duplicate_member_is_refused",
        ),
        Case(
            "archive",
            "FMU: member `..\\evil.txt`",
            lambda: open_fmu(
                rewrite(whitebox, tmp / "win.fmu", add=[(zipfile.ZipInfo("..\\evil.txt"), b"x")])
            ),
            here + "test_windows_style_escapes_are_refused",
        ),
        Case(
            "archive",
            "FMU: a member with an empty name",
            lambda: open_fmu(
                rewrite(whitebox, tmp / "noname.fmu", add=[(zipfile.ZipInfo(""), b"x")])
            ),
            here + "test_random_member_names_never_escape",
        ),
        Case("archive", "FMU: empty file", empty, here + "test_empty_truncated_or_folder"),
        Case(
            "archive",
            "FMU: a folder (unpacked FMU)",
            folder,
            here + "test_empty_truncated_or_folder",
        ),
        Case(
            "archive",
            "FMU: XML external entity (file:///etc/hostname)",
            xml_entity("external"),
            here + "test_external_entity_is_not_resolved",
        ),
        Case(
            "archive",
            "FMU: XML entity expansion bomb",
            xml_entity("bomb"),
            here + "test_entity_expansion_bomb_is_refused",
        ),
        Case(
            "archive",
            "FMU: binary that is not a shared library",
            binary(b"\x7fELF not really", "junk_binary.fmu"),
            here + "test_binary_that_does_not_load_is_an_archive_error",
        ),
        Case(
            "archive",
            "FMU: binary without the FMI functions",
            binary(Path(_ctypes.__file__).read_bytes(), "foreign_binary.fmu"),
            here + "test_binary_that_does_not_load_is_an_archive_error",
        ),
        Case(
            "archive",
            "FMU: modelDescription.xml of another build (GUID)",
            foreign_guid,
            here + "test_model_description_of_another_build_is_refused_at_instantiation",
        ),
        Case(
            "archive",
            "FMU: a pythonfmu FMU without `resources/slavemodule.txt`, or naming a module it "
            "lacks (issue 42, item 3: pythonfmu's binary segfaulted the host at instantiation)",
            without_slave_module,
            "test_export.py::test_python_fmu_without_its_slave_module_is_refused_before_loading",
        ),
        Case(
            "archive",
            "FMU: variable name misspelled",
            misspelled_variable,
            "test_fmu_archive.py::test_reference_fmu_opens_and_cleans_up",
        ),
    ]
    return cases


# ---------------------------------------------------------------------------- project files


def config_cases(tmp: Path) -> list[Case]:
    raw = tomllib.loads(REFERENCE.read_text(encoding="utf-8"))
    fields = "test_config.py::test_every_error_names_its_field"
    fuzz = "test_robustness_config.py::test_any_field_set_to_any_value"

    def edited(edit: Callable[[dict], object]) -> Callable[[], object]:
        def make() -> object:
            copy = json.loads(json.dumps(raw))
            edit(copy)
            return parse_config(copy, REFERENCE)

        return make

    def text(content: bytes, name: str) -> Callable[[], object]:
        def make() -> object:
            (tmp / name).write_bytes(content)
            return load_config(tmp / name)

        return make

    return [
        Case(
            "config",
            "project: misspelled section `[stagse]`",
            edited(lambda r: r.update(stagse=r.pop("stages"))),
            fields,
        ),
        Case(
            "config", "project: `[whitebox]` missing", edited(lambda r: r.pop("whitebox")), fields
        ),
        Case(
            "config",
            "project: an acceptance band above the Nyquist frequency of `step` or `resample` "
            "(issue 42, item 10: accepted, then every frequency check UNDECIDED for another "
            "reason)",
            edited(
                lambda r: r.update(
                    whitebox={**r["whitebox"], "step": 0.001}, acceptance={"band": [600, 900]}
                )
            ),
            "test_acceptance.py::test_a_band_above_the_nyquist_frequency_is_refused_at_load",
        ),
        Case(
            "config",
            'project: `step = "fast"`',
            edited(lambda r: r["whitebox"].update(step="fast")),
            fields,
        ),
        Case(
            "config",
            "project: `train_fraction = 10**400`",
            edited(lambda r: r["split"].update(train_fraction=10**400)),
            "test_robustness_config.py::test_integer_too_large_for_a_float_is_a_config_error",
        ),
        Case(
            "config",
            "project: role `forse`",
            edited(lambda r: r["signals"]["load_force"].update(role="forse")),
            fields,
        ),
        Case(
            "config",
            "project: unit `Pa` for a force",
            edited(lambda r: r["signals"]["load_force"].update(unit="Pa")),
            fields,
        ),
        Case(
            "config",
            "project: stage target misspelled",
            edited(lambda r: r["stages"][1].update(target="ram_positon")),
            fields,
        ),
        Case(
            "config",
            "project: stages feeding each other in a cycle",
            edited(lambda r: r["stages"][0].update(feeds_from=["ITFV"])),
            "test_config.py::test_cycle_is_reported_as_a_cycle",
        ),
        Case(
            "config",
            "project: unknown key `gp.inducng`",
            edited(lambda r: r["gp"].update(inducng=3)),
            "test_robustness_config.py::test_unknown_key_is_named_with_the_allowed_ones",
        ),
        Case(
            "config",
            "project: a table where a number belongs (`gp.seed = {}`)",
            edited(lambda r: r["gp"].update(seed={})),
            fuzz,
        ),
        Case(
            "config",
            "project: a date where a number belongs",
            edited(lambda r: r["whitebox"].update(step=datetime.date(2024, 1, 1))),
            "test_robustness_config.py::test_dates_and_times_are_not_numbers",
        ),
        Case(
            "config",
            "project: invalid TOML",
            text(b"[whitebox\nfmu = 1", "broken.toml"),
            "test_config.py::test_invalid_toml_and_unreadable_file",
        ),
        Case(
            "config",
            "project: not UTF-8",
            text(b"\xff\xfe[gp]", "utf16.toml"),
            "test_robustness_config.py::test_binary_and_non_utf8_files",
        ),
    ]


# ---------------------------------------------------------------------------- recordings


def recording_cases(tmp: Path, whitebox: Path, recording: Recording) -> list[Case]:
    loaders = "test_recording.py::"
    prop = "test_robustness_recording.py::test_every_defect_names_its_column_row_and_file_line"

    def csv(content: str, name: str) -> Callable[[], object]:
        def make() -> object:
            (tmp / name).write_text(content, encoding="utf-8")
            return load_recording(tmp / name)

        return make

    def header_unit(unit: str, scale: float) -> Callable[[], object]:
        def make() -> tuple[str, str] | object:
            frame = recording.to_frame()
            frame["valve_current"] *= scale
            units = {**recording.units, "valve_current": unit}
            frame.columns = ["time [s]", *(f"{n} [{units[n]}]" for n in recording.names)]
            frame.to_csv(tmp / "amps.csv", index=False)
            result = simulate_recording(whitebox, load_recording(tmp / "amps.csv"))
            reference = simulate_recording(whitebox, recording)
            worst = max(
                float(np.max(np.abs(result[n] - reference[n])) / (np.ptp(reference[n]) or 1.0))
                for n in result.names
            )
            return "converted", f"outputs within {worst:.1e} of their range of the run in mA"

        return make

    def renamed() -> object:
        signals = {
            ("load_force_N" if n == "load_force" else n): v for n, v in recording.signals.items()
        }
        return simulate_recording(whitebox, Recording(recording.time, signals, source="bench.csv"))

    def not_utf8() -> object:
        (tmp / "latin1.csv").write_bytes("time,débit\n0,1\n1,2\n".encode("latin-1"))
        return load_recording(tmp / "latin1.csv")

    rows = "time,x\n0,1\n0.1,2\n0.2,3\n0.3,4\n"
    return [
        Case(
            "recording",
            "CSV: empty file",
            csv("", "empty.csv"),
            loaders + "test_csv_structure_errors",
        ),
        Case(
            "recording",
            "CSV: header only",
            csv("time,x\n", "header.csv"),
            loaders + "test_csv_structure_errors",
        ),
        Case(
            "recording",
            "CSV: no header line",
            csv("0,1\n1,2\n", "noheader.csv"),
            loaders + "test_csv_structure_errors",
        ),
        Case("recording", "CSV: NaN in a column", csv(rows.replace(",3", ",nan"), "nan.csv"), prop),
        Case("recording", "CSV: inf in a column", csv(rows.replace(",3", ",inf"), "inf.csv"), prop),
        Case("recording", "CSV: empty cell", csv(rows.replace(",3", ","), "gap.csv"), prop),
        Case(
            "recording",
            "CSV: text in a number column",
            csv(rows.replace(",3", ",open"), "text.csv"),
            prop,
        ),
        Case(
            "recording",
            "CSV: decimal comma",
            csv("time;x\n0;1\n0.1;2\n0.2;1,5\n0.3;4\n", "comma.csv"),
            prop,
        ),
        Case(
            "recording",
            "CSV: repeated time stamp",
            csv(rows.replace("0.2,", "0.1,"), "dup.csv"),
            prop,
        ),
        Case(
            "recording",
            "CSV: time going back",
            csv(rows.replace("0.2,", "0.05,"), "back.csv"),
            prop,
        ),
        Case(
            "recording",
            "CSV: uneven time step",
            csv(rows.replace("0.3,", "0.35,"), "uneven.csv"),
            prop,
        ),
        Case(
            "recording",
            "CSV: time column misspelled",
            csv(rows.replace("time", "Time"), "Time.csv"),
            loaders + "test_csv_missing_time_column_names_columns_and_option",
        ),
        Case("recording", "CSV: not UTF-8", not_utf8, loaders + "test_csv_not_utf8"),
        Case(
            "recording",
            "recording: missing file",
            lambda: load_recording(tmp / "absent.csv"),
            loaders + "test_missing_file_names_path_and_reason",
        ),
        Case(
            "recording",
            "recording: unsupported format",
            csv("x", "rec.xlsx"),
            loaders + "test_unsupported_extension_lists_supported",
        ),
        Case(
            "recording",
            "header unit `[A]` where the FMU declares mA",
            header_unit("A", 1e-3),
            "test_simulate.py::test_compatible_unit_is_converted_with_a_note",
        ),
        Case(
            "recording",
            "header unit `[V]` where the FMU declares mA",
            header_unit("V", 1.0),
            "test_simulate.py::test_incompatible_unit_names_both_units",
        ),
        Case(
            "recording",
            "FMU input missing from the recording (column renamed)",
            renamed,
            "test_simulate.py::test_missing_input_names_input_closest_column_and_options",
        ),
    ]


# ---------------------------------------------------------------------------- model folders


def model_cases(tmp: Path, saved: Path) -> list[Case]:
    here = "test_robustness_model.py::"

    def tampered(name: str, edit: Callable[[Path], object], rehash: bool = False):
        def make() -> object:
            folder = tmp / f"model_{name}"
            shutil.copytree(saved, folder)
            edit(folder)
            if rehash:
                manifest = json.loads((folder / MANIFEST).read_text())
                manifest["files"] = {n: file_sha256(folder / n) for n in manifest["files"]}
                manifest[MANIFEST_HASH] = manifest_digest(manifest)
                (folder / MANIFEST).write_text(json.dumps(manifest))
            return load_model(folder)

        return make

    def flip(name: str) -> Callable[[Path], object]:
        def edit(folder: Path) -> None:
            data = bytearray((folder / name).read_bytes())
            data[len(data) // 2] ^= 0x01
            (folder / name).write_bytes(bytes(data))

        return edit

    def manifest_edit(change: Callable[[dict], object]) -> Callable[[Path], object]:
        def edit(folder: Path) -> None:
            manifest = json.loads((folder / MANIFEST).read_text())
            change(manifest)
            (folder / MANIFEST).write_text(json.dumps(manifest))

        return edit

    def plant_pickle(folder: Path) -> None:
        (folder / "stage_RAM.npz").write_bytes(pickle.dumps({"not": "arrays"}))
        meta = json.loads((folder / "stage_RAM.json").read_text())
        meta["arrays_sha256"] = file_sha256(folder / "stage_RAM.npz")
        (folder / "stage_RAM.json").write_text(json.dumps(meta))

    def unknown_setting(folder: Path) -> None:
        meta = json.loads((folder / "stage_ITFV.json").read_text())
        meta["settings"]["bogus"] = 1
        (folder / "stage_ITFV.json").write_text(json.dumps(meta))

    return [
        Case(
            "model",
            "model: a byte flipped in `stage_RAM.npz`",
            tampered("flip_npz", flip("stage_RAM.npz")),
            here + "test_a_flipped_byte_anywhere_is_refused_naming_the_file",
        ),
        Case(
            "model",
            "model: a byte flipped in `stage_EHV.json`",
            tampered("flip_json", flip("stage_EHV.json")),
            here + "test_a_flipped_byte_anywhere_is_refused_naming_the_file",
        ),
        Case(
            "model",
            "model: `dt` edited in `model.json` (still valid JSON)",
            tampered("dt", manifest_edit(lambda m: m.update(dt=0.5))),
            here + "test_valid_json_edits_of_the_manifest_are_refused",
        ),
        Case(
            "model",
            "model: `whitebox.fmu` deleted",
            tampered("missing", lambda f: (f / "whitebox.fmu").unlink()),
            here + "test_each_missing_file_is_named",
        ),
        Case(
            "model",
            f"model: format version {FORMAT_VERSION + 1}, newer than this tool's",
            tampered(
                "version",
                manifest_edit(lambda m: m.update(format_version=FORMAT_VERSION + 1)),
                rehash=True,
            ),
            here + "test_valid_json_edits_of_the_manifest_are_refused",
        ),
        Case(
            "model",
            "model: pickle planted as `stage_RAM.npz`, every hash recomputed",
            tampered("pickle", plant_pickle, rehash=True),
            here + "test_planted_pickle_is_refused_and_never_executed",
        ),
        Case(
            "model",
            "model: stage file stem `../../elsewhere`, hashes recomputed",
            tampered(
                "escape",
                manifest_edit(lambda m: m["stages"][0].update(stem="../../elsewhere")),
                rehash=True,
            ),
            here + "test_rehashed_but_malformed_manifest_is_refused",
        ),
        Case(
            "model",
            "model: a stage renamed, hashes recomputed",
            tampered(
                "renamed", manifest_edit(lambda m: m["stages"][0].update(name="SPOOL")), rehash=True
            ),
            here + "test_rehashed_but_malformed_manifest_is_refused",
        ),
        Case(
            "model",
            "model: unknown setting in `stage_ITFV.json`, hashes recomputed",
            tampered("setting", unknown_setting, rehash=True),
            here + "test_stage_file_edited_then_rehashed",
        ),
        Case(
            "model",
            "model: `manifest_sha256` deleted from a current `model.json` (issue 42, item 8: "
            "it switched the tamper check off)",
            tampered("unhashed", manifest_edit(lambda m: m.pop(MANIFEST_HASH))),
            here + "test_a_current_manifest_without_its_own_hash_is_refused",
        ),
        Case(
            "model",
            "model: `model.json` is a JSON list",
            tampered("list", lambda f: (f / MANIFEST).write_text("[]")),
            here + "test_manifest_that_is_not_an_object",
        ),
        Case(
            "model",
            "model: a folder that is not a model",
            lambda: load_model(tmp),
            "test_greybox.py::test_model_folder_round_trip_and_tamper_detection",
        ),
    ]


# ---------------------------------------------------------------------------- runs


def run_cases(
    tmp: Path, whitebox: Path, truth: Path, recording: Recording, saved: Path, model
) -> list[Case]:
    runs = "test_robustness_runs.py::"

    def step(values: list[float], h: float) -> Callable[[], object]:
        def make() -> object:
            inputs = ["valve_current", "supply_pressure", "load_force", "engage"]
            with open_fmu(whitebox) as archive, FmuInstance(archive, inputs, []) as fmu:
                fmu.step([0.0, 20.7e6, 0.0, 1.0], 1e-3)
                return fmu.step(values, h)

        return make

    def tunable_mid_run() -> object:
        with open_fmu(truth) as archive, FmuInstance(archive, [], ["ram_position"]) as fmu:
            for _ in range(5):
                fmu.step([], 1e-3)
            fmu.set_real(["time_delay"], [0.06])
            return fmu.step([], 1e-3)

    def absurd_input() -> object:
        current = np.where(np.arange(recording.n_samples) >= 100, 1e300, recording["valve_current"])
        return simulate_recording(whitebox, recording.with_signals({"valve_current": current}))

    def interrupted_write() -> tuple[str, str]:
        import fmu_greybox.gp.storage as storage

        folder = tmp / "kept"
        shutil.copytree(saved, folder)
        before = snapshot(folder)
        original, calls = storage.save, []

        def ctrl_c(*args, **kwargs):
            calls.append(original(*args, **kwargs))
            if len(calls) == 2:
                raise KeyboardInterrupt
            return calls[-1]

        storage.save = ctrl_c
        try:
            save_model(model, folder)
        except KeyboardInterrupt:
            pass
        finally:
            storage.save = original
        return "`KeyboardInterrupt` (passed on)", left_behind(folder, before)

    def killed_write() -> tuple[str, str]:
        folder = tmp / "killed"
        shutil.copytree(saved, folder)
        project = REFERENCE.read_text(encoding="utf-8")
        for old, new in (
            ('"builtin:HydraulicActuator"', repr(str(whitebox))),
            ("inducing = 300", "inducing = 8"),
            ("max_iter = 200", "max_iter = 3"),
        ):
            project = project.replace(old, new)
        (tmp / "project.toml").write_text(project, encoding="utf-8")
        save_recording(recording, tmp / "rec.csv")
        before, marker = snapshot(folder), tmp / "stalled"
        stall = ["fmu_greybox.gp.storage", "", "save", "2", str(marker)]
        train = ["-q", "train", str(tmp / "project.toml"), "--recording", str(tmp / "rec.csv")]
        command = [sys.executable, "-c", runs_tests.STALLED_RUN, *stall, *train, "--out", folder]
        process = subprocess.Popen(command)
        while not marker.exists() and process.poll() is None:
            time.sleep(0.05)
        process.send_signal(signal.SIGKILL)
        process.wait()
        return f"killed ({signal.Signals(-process.returncode).name})", left_behind(folder, before)

    def after_killed() -> tuple[str, str]:
        folder = tmp / "killed"
        for debris in folder.parent.glob(f".{folder.name}.*.tmp"):
            stamp = time.time() - 60  # older than the writer's grace period
            os.utime(debris, (stamp, stamp))
        train = ["-q", "train", str(tmp / "project.toml"), "--recording", str(tmp / "rec.csv")]
        command = [sys.executable, "-c", "from fmu_greybox.cli import main; main()", *train]
        result = subprocess.run([*command, "--out", folder], check=False)
        left = sorted(p.name for p in folder.parent.iterdir() if p.name.startswith(".killed."))
        loads = "loads" if load_model(folder) else "fails"
        return f"exit {result.returncode}", f"killed/ {loads}; left: {', '.join(left) or 'none'}"

    def failed_save() -> tuple[str, str]:
        (tmp / "wb.csv").write_text("time,x\n0,1\n1,2\n")
        before = snapshot(tmp / "wb.csv")
        try:
            save_recording(recording, tmp / "wb.csv" / "rec.csv")
        except FmuGreyboxError as error:
            kept = "intact" if snapshot(tmp / "wb.csv") == before else "CHANGED"
            return f"`{type(error).__name__}`", f"{error} (the file wb.csv is {kept})"
        return "no exception", "saved into a file?"

    return [
        Case(
            "run",
            "input NaN sent to the FMU",
            step([np.nan, 20.7e6, 0.0, 1.0], 1e-3),
            "test_fmu_archive.py::test_instance_errors_carry_call_status_and_time",
        ),
        Case(
            "run",
            "negative communication step",
            step([0.0, 20.7e6, 0.0, 1.0], -1e-3),
            "test_fmu_archive.py::test_instance_errors_carry_call_status_and_time",
        ),
        Case(
            "run",
            "parameter out of range at initialisation",
            lambda: simulate_recording(truth, recording, parameters={"time_delay": 0.06}),
            "test_simulate.py::test_parameter_out_of_range_fails_at_initialisation",
        ),
        Case(
            "run",
            "tunable parameter made invalid mid-run",
            tunable_mid_run,
            runs + "test_parameter_made_invalid_mid_run_names_the_call_and_time",
        ),
        Case(
            "run",
            "FMU failing mid-run: delay line overflow (truth FMU)",
            lambda: simulate_recording(
                truth, recording, parameters={"time_delay": 0.05, "solver_step": 1e-5}
            ),
            "test_simulate.py::test_fmu_failing_mid_run_raises_fmu_error",
        ),
        Case(
            "run",
            "FMU failing mid-run: absurd input from row 100",
            absurd_input,
            runs + "test_simulate_failing_mid_run_keeps_the_earlier_output",
        ),
        Case(
            "run",
            "Ctrl-C while `train` writes over an earlier model",
            interrupted_write,
            "test_greybox.py::test_failed_save_leaves_the_previous_model_intact",
        ),
        Case(
            "run",
            "`fmu-greybox train` killed (SIGKILL) while writing over an earlier model",
            killed_write,
            runs + "test_sigkill_leaves_the_earlier_model_intact",
        ),
        Case(
            "run",
            "the next `train` into the folder of the killed one",
            after_killed,
            runs + "test_sigkill_leaves_the_earlier_model_intact",
        ),
        Case(
            "run",
            "saving a recording to a path under a file",
            failed_save,
            "test_recording.py::test_save_errors",
        ),
    ]


# ---------------------------------------------------------------------------- workflow


def workflow_cases(tmp: Path, whitebox: Path, recording: Recording, saved: Path) -> list[Case]:
    """Misuse of train, validate, diagnose and export (issue 15)."""
    from click.testing import CliRunner
    from scipy.io import savemat

    from fmu_greybox.atomic import output_lock
    from fmu_greybox.cli import main as cli
    from fmu_greybox.diagnosis import Diagnosis

    flow = "test_robustness_workflow.py::"
    evidence = "test_robustness_evidence.py::"
    model = load_model(saved)
    config = parse_config(small_project(whitebox), REFERENCE)
    save_recording(recording, tmp / "train.csv")

    def edited(**tables: dict) -> object:
        raw = small_project(whitebox)
        for name, values in tables.items():
            raw[name] = {**raw[name], **values}
        return parse_config(raw, tmp / "edited.toml")

    def byte_copy() -> tuple[str, str]:
        shutil.copyfile(tmp / "train.csv", tmp / "copy.csv")  # without train.csv.units.json
        result = validate_model(model, load_project_recording(config, tmp / "copy.csv"))
        return "scored", f"copy.csv: {result.held_out}"

    def rounded(digits: int, name: str) -> Path:
        """train.csv re-saved with ``digits`` significant digits, no units file."""
        header, *lines = (tmp / "train.csv").read_text(encoding="utf-8").splitlines()
        rows = [",".join(f"{float(v):.{digits}g}" for v in line.split(",")) for line in lines]
        (tmp / name).write_text("\n".join([header, *rows]) + "\n", encoding="utf-8")
        return tmp / name

    def rounded_copy(digits: int) -> tuple[str, str]:
        copy = rounded(digits, f"sig{digits}.csv")
        result = validate_model(model, load_project_recording(config, copy))
        return "scored", f"{copy.name}: {result.held_out}"

    def calibrate_on_itself() -> object:
        training = load_project_recording(config, tmp / "train.csv")
        copy = load_project_recording(config, rounded(12, "calibration.csv"))
        return train_model(config, training, calibration_recordings=[copy])

    def validate_twice() -> object:
        same = load_project_recording(config, tmp / "train.csv")
        copy = load_project_recording(config, rounded(15, "again.csv"))
        return validate_recordings(model, {"1-train": same, "2-again": copy})

    def older_folder() -> tuple[str, str]:
        folder = tmp / "model_v2"
        shutil.copytree(saved, folder)
        manifest = json.loads((folder / MANIFEST).read_text(encoding="utf-8"))
        manifest["format_version"] = 2
        del manifest["files"][TRAINING_ROWS]
        (folder / TRAINING_ROWS).unlink()
        manifest[MANIFEST_HASH] = manifest_digest(manifest)
        (folder / MANIFEST).write_text(json.dumps(manifest), encoding="utf-8")
        copy = load_project_recording(config, rounded(12, "old.csv"))
        return "scored", f"old.csv: {validate_model(load_model(folder), copy).held_out}"

    def resampled(step: float, source: str) -> Recording:
        grid = np.arange(0.0, recording.duration + step / 2, step)
        signals = {n: np.interp(grid, recording.time, v) for n, v in recording.signals.items()}
        return Recording(grid, signals, recording.units, source)

    def milliseconds() -> object:
        frame = recording.to_frame()
        frame["time"] *= 1000.0
        frame.to_csv(tmp / "ms.csv", index=False)
        return validate_model(model, load_project_recording(config, tmp / "ms.csv"))

    def other_column() -> object:
        raw = small_project(whitebox)
        raw["signals"]["load_force"]["column"] = "F_load"
        return check_project(parse_config(raw, tmp / "other.toml"), model, "model")

    def short(rows: int) -> Recording:
        return Recording(
            recording.time[:rows],
            {n: v[:rows] for n, v in recording.signals.items()},
            recording.units,
            f"{rows}rows.csv",
        )

    def cli_outcome(args: list[str], written: Path) -> tuple[str, str]:
        result = CliRunner().invoke(cli, args)
        left = "written" if written.exists() else "not written"
        return f"exit {result.exit_code}", f"{result.output.strip()} ({written.name}: {left})"

    def export_under_a_file() -> tuple[str, str]:
        (tmp / "blocker").write_text("a file")
        out = tmp / "new" / "greybox.fmu"
        args = ["export", str(saved), "--out", str(out), "--ssp", str(tmp / "blocker" / "b.ssp")]
        return cli_outcome([*args, "--recording", str(tmp / "train.csv")], out)

    def busy_folder() -> tuple[str, str]:
        (tmp / "project.toml").write_text(REFERENCE.read_text(encoding="utf-8"))
        args = ["train", str(tmp / "project.toml"), "--recording", str(tmp / "train.csv")]
        with output_lock(tmp / "busy", "--out"):
            return cli_outcome([*args, "--out", str(tmp / "busy")], tmp / "busy")

    def two_structs() -> object:
        struct = {"time": recording.time, "x": recording["valve_current"]}
        savemat(tmp / "two.mat", {"run1": struct, "run2": struct})
        return load_recording(tmp / "two.mat")

    def shared_column() -> object:
        raw = small_project(whitebox)
        raw["signals"]["load_force"]["column"] = "supply_pressure"
        return parse_config(raw, tmp / "shared.toml")

    return [
        Case(
            "workflow",
            "validate: a byte copy of the training CSV without its units file",
            byte_copy,
            flow + "test_byte_copy_without_units_scores_only_the_held_out_rows",
        ),
        *(
            Case(
                "workflow",
                f"validate: the training CSV re-saved with {digits} significant digits "
                "(issue 42, item 5: every row was scored as unseen)",
                lambda digits=digits: rounded_copy(digits),
                evidence + "test_a_rounded_copy_of_the_training_csv_scores_only_its_held_out_rows",
            )
            for digits in (15, 12)
        ),
        Case(
            "workflow",
            "`train --calibrate-on` the training recording, or a copy (byte, rounded) (issue 42, "
            "item 6: σ was calibrated on the training rows)",
            calibrate_on_itself,
            evidence + "test_calibrating_on_the_training_recording_is_refused",
        ),
        Case(
            "workflow",
            "`validate` given one recording twice (a copy, rounded or with other time stamps) "
            "(issue 42, item 7: it counted twice, narrowing the coverage interval); "
            "`train --calibrate-on` likewise",
            validate_twice,
            evidence + "test_the_same_recording_twice_to_validate_is_refused",
        ),
        Case(
            "workflow",
            "validate: a model folder of format 2 (no row digests) with a rounded copy of its "
            "training CSV (issue 42, item 9: every row scored, silently); format 3-4 (exact "
            "digests) likewise",
            older_folder,
            evidence + "test_an_older_model_folder_recognises_a_rounded_copy_by_its_spread_and_"
            "says_so",
        ),
        Case(
            "workflow",
            "validate: a 2 kHz recording for a 1 kHz model",
            lambda: validate_model(model, resampled(recording.dt / 2, "2kHz.csv")),
            flow + "test_another_sample_time_is_refused",
        ),
        Case(
            "workflow",
            "validate: time in milliseconds without a unit",
            milliseconds,
            flow + "test_time_in_milliseconds_without_a_unit_is_pointed_out",
        ),
        Case(
            "workflow",
            "validate: a project with another `column` than the training one",
            other_column,
            flow + "test_a_project_other_than_the_training_one_is_refused",
        ),
        Case(
            "workflow",
            "train: a recorded input also in `[whitebox] fixed_inputs`",
            lambda: train_model(
                c := edited(whitebox={"fixed_inputs": {"supply_pressure": 2e7}}),
                load_project_recording(c, tmp / "train.csv"),
            ),
            flow + "test_recorded_input_in_fixed_inputs_is_refused",
        ),
        Case(
            "workflow",
            "train: `train_fraction = 0.001`",
            lambda: train_model(edited(split={"train_fraction": 0.001}), recording),
            flow + "test_too_few_training_rows_are_refused",
        ),
        Case(
            "workflow",
            "train: more inducing points than training rows",
            lambda: train_model(edited(gp={"inducing": 1000}), recording),
            flow + "test_more_inducing_points_than_rows_are_refused",
        ),
        Case(
            "workflow",
            "diagnose: 10 rows",
            lambda: Diagnosis(config, greybox=None).fit(short(10)),
            flow + "test_diagnosis_on_too_few_rows_is_refused",
        ),
        Case(
            "workflow",
            "`export --ssp` into a folder under a file",
            export_under_a_file,
            flow + "test_export_ssp_under_a_file_is_refused_before_anything_is_written",
        ),
        Case(
            "workflow",
            "`train --out` into a folder another run is writing",
            busy_folder,
            flow + "test_second_train_into_a_busy_folder_is_refused",
        ),
        Case(
            "workflow",
            "two signals sharing one `column`",
            shared_column,
            flow + "test_two_signals_reading_one_column_are_refused",
        ),
        Case(
            "workflow",
            "a `.mat` file with two structs",
            two_structs,
            "test_recording_formats.py::test_mat_with_two_structs_says_why_and_how",
        ),
    ]


def small_project(whitebox: Path) -> dict:
    """The reference project's tables with this white-box, a small GP and 80 % training."""
    raw = tomllib.loads(REFERENCE.read_text(encoding="utf-8"))
    raw["whitebox"]["fmu"] = str(whitebox)
    raw["gp"].update(inducing=8, max_iter=3)
    raw["split"] = {"train_fraction": 0.8}
    return raw


# ---------------------------------------------------------------------------- main


def snapshot(path: Path) -> dict[str, bytes]:
    """Every file at or below ``path`` with its bytes."""
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    return {str(p): p.read_bytes() for p in files}


def left_behind(folder: Path, before: dict[str, bytes]) -> str:
    """What an interrupted write left: the earlier folder's state and any temporaries."""
    state = "intact and loads" if snapshot(folder) == before and load_model(folder) else "CHANGED"
    debris = sorted(p for p in folder.parent.iterdir() if p.name.startswith(f".{folder.name}."))
    kept = [f"{p.name} ({'with' if (p / MANIFEST).exists() else 'no'} {MANIFEST})" for p in debris]
    return f"earlier {folder.name}/ {state}; temporaries left: {', '.join(kept) or 'none'}"


def train_small(tmp: Path, whitebox: Path, truth: Path) -> tuple[Recording, Path, object]:
    """A 0.5 s recording and a small model trained on its first 80 %, saved in ``tmp/model``."""
    request = SynthRequest(
        effects={"gain_error": 0.1}, seed=5, noise=0.0, profile=FlightTestProfile(duration=0.5)
    )
    with open_fmu(truth) as truth_archive, open_fmu(whitebox) as whitebox_archive:
        recording = synthesise(truth_archive, whitebox_archive, request)
    model = train_model(parse_config(small_project(whitebox), REFERENCE), recording)
    return recording, save_model(model, tmp / "model"), model


def main() -> None:
    sections = {
        "archive": "FMU archives",
        "config": "Project files",
        "recording": "Recordings",
        "model": "Model folders",
        "run": "Runs",
        "workflow": "Train, validate, diagnose, export",
    }
    with tempfile.TemporaryDirectory() as folder:
        tmp = Path(folder)
        fmus = {name: shutil.copy(path, tmp / path.name) for name, path in reference_fmus().items()}
        whitebox, truth = Path(fmus["HydraulicActuator"]), Path(fmus["HydraulicActuatorTruth"])
        recording, saved, model = train_small(tmp, whitebox, truth)
        cases = [
            *archive_cases(tmp, whitebox, saved),
            *config_cases(tmp),
            *recording_cases(tmp, whitebox, recording),
            *model_cases(tmp, saved),
            *run_cases(tmp, whitebox, truth, recording, saved, model),
            *workflow_cases(tmp, whitebox, recording, saved),
        ]
        for key, title in sections.items():
            print(f"\n### {title}\n")
            print("| Bad input | Gets | Message (abbreviated) | Test |")
            print("|---|---|---|---|")
            for case in (c for c in cases if c.section == key):
                gets, message = outcome(case, tmp)
                print(f"| {case.what} | {gets} | {message} | `{case.test}` |")


if __name__ == "__main__":
    main()
