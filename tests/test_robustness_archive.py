"""Hostile and damaged FMU archives beyond tests/test_fmu_archive.py (issue 7, section 4).

test_fmu_archive.py already refuses ``../`` and absolute members, symbolic links, a high
compression ratio, a non-zip file, a zip without ``modelDescription.xml``, neither interface,
FMI 3.0, no binary for this platform and malformed XML. Here: absurd *declared* sizes (per member
and in total, refused before extraction), sizes that lie, damaged streams, encryption, compression
methods FMI does not allow, duplicate members, Windows paths, folders, binaries that do not load,
a foreign GUID, XML entity tricks, and property tests over random member names and byte damage.
"""

from __future__ import annotations

import _ctypes
import os
import struct
import zipfile
from pathlib import Path

import pytest
import test_fmu_archive as archive_tests
from fmpy import platform as fmpy_platform
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fmu_greybox.errors import FmuArchiveError, FmuError
from fmu_greybox.fmi.archive import (
    MAX_COMPRESSION_RATIO,
    MAX_MEMBER_BYTES,
    MAX_UNCOMPRESSED_BYTES,
    open_fmu,
)
from fmu_greybox.fmi.instance import FmuInstance

rewrite = archive_tests.rewrite
temp_root = archive_tests.temp_root  # fixture: open_fmu's private temporary folder

FUZZ = settings(
    max_examples=30,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
LIBRARY = f"binaries/{fmpy_platform}/HydraulicActuator.so"


def stored(name: str) -> zipfile.ZipInfo:
    """A member written without compression (its bytes appear verbatim in the archive)."""
    info = zipfile.ZipInfo(name)
    info.compress_type = zipfile.ZIP_STORED
    return info


def patch_central(path: Path, name: str, **fields: int) -> Path:
    """Overwrite fields of ``name``'s central-directory record in place.

    ``fields``: ``flags``, ``method``, ``compress_size`` and ``file_size`` (what
    :class:`zipfile.ZipInfo` reports as ``flag_bits``, ``compress_type``, ...).
    """
    offsets = {
        "flags": (8, "<H"),
        "method": (10, "<H"),
        "compress_size": (20, "<I"),
        "file_size": (24, "<I"),
    }
    data = bytearray(path.read_bytes())
    pos = data.find(b"PK\x01\x02")
    while pos >= 0:
        length = struct.unpack_from("<H", data, pos + 28)[0]
        if data[pos + 46 : pos + 46 + length] == name.encode():
            for key, value in fields.items():
                offset, fmt = offsets[key]
                struct.pack_into(fmt, data, pos + offset, value)
            path.write_bytes(bytes(data))
            return path
        pos = data.find(b"PK\x01\x02", pos + 4)
    raise KeyError(name)


def refused(fmu: Path, pattern: str) -> FmuArchiveError:
    """Open ``fmu``, expecting a refusal that names the file and matches ``pattern``."""
    with pytest.raises(FmuArchiveError, match=pattern) as info:
        open_fmu(fmu)
    assert str(fmu) in str(info.value)
    return info.value


def extracted_nothing(temp_root: Path) -> bool:
    """Whether open_fmu left nothing behind in its temporary folder."""
    return not list(temp_root.iterdir())


# ------------------------------------------------------------------------- declared sizes


def test_absurd_declared_member_size_is_refused_before_extraction(
    whitebox_fmu: Path, tmp_path: Path, temp_root: Path
) -> None:
    fmu = rewrite(whitebox_fmu, tmp_path / "huge.fmu", add=[(stored("resources/huge.bin"), b"x")])
    patch_central(fmu, "resources/huge.bin", compress_size=0xFFFFFFF0, file_size=0xFFFFFFF0)
    error = refused(
        fmu,
        r"member 'resources/huge\.bin' declares 4\.0 GiB uncompressed, over "
        r"the 1\.0 GiB limit per member; refused before extraction",
    )
    assert MAX_MEMBER_BYTES < 0xFFFFFFF0 and "corrupt or hostile" in str(error)
    assert extracted_nothing(temp_root)


def test_total_declared_size_is_capped(whitebox_fmu: Path, tmp_path: Path, temp_root: Path) -> None:
    parts = [(stored(f"resources/part{i}.bin"), b"x") for i in range(3)]
    fmu = rewrite(whitebox_fmu, tmp_path / "parts.fmu", add=parts)
    each = MAX_MEMBER_BYTES - 1  # every member within its own limit, ratio 1
    for i in range(3):
        patch_central(fmu, f"resources/part{i}.bin", compress_size=each, file_size=each)
    assert 3 * each > MAX_UNCOMPRESSED_BYTES
    refused(
        fmu,
        r"uncompressed size 3\.0 GiB \(all members\) exceeds the 2\.0 GiB limit; "
        r"refused before extraction",
    )
    assert extracted_nothing(temp_root)


def test_declared_size_without_compressed_bytes_is_a_zip_bomb(
    whitebox_fmu: Path, tmp_path: Path, temp_root: Path
) -> None:
    fmu = rewrite(whitebox_fmu, tmp_path / "empty.fmu", add=[(stored("resources/e.bin"), b"")])
    patch_central(fmu, "resources/e.bin", file_size=50_000)
    refused(
        fmu,
        rf"member 'resources/e\.bin' expands 50000 times; refused as a likely zip bomb "
        rf"\(the limit is {MAX_COMPRESSION_RATIO:.0f} times\)",
    )
    assert extracted_nothing(temp_root)


def test_member_larger_than_declared_is_cut_at_its_declared_size(
    whitebox_fmu: Path, tmp_path: Path, temp_root: Path
) -> None:
    lie = zipfile.ZipInfo("resources/lie.bin")
    lie.compress_type = zipfile.ZIP_DEFLATED
    fmu = rewrite(whitebox_fmu, tmp_path / "lie.fmu", add=[(lie, os.urandom(64) * 1000)])
    patch_central(fmu, "resources/lie.bin", file_size=100)
    refused(
        fmu,
        r"member 'resources/lie\.bin' cannot be extracted \(Bad CRC-32.*\); the archive "
        r"is damaged; re-export the FMU",
    )
    assert extracted_nothing(temp_root)


def test_damaged_deflate_stream_names_the_member(
    whitebox_fmu: Path, tmp_path: Path, temp_root: Path
) -> None:
    fmu = tmp_path / "damaged.fmu"
    fmu.write_bytes(whitebox_fmu.read_bytes())
    with zipfile.ZipFile(fmu) as zf:
        info = zf.getinfo(LIBRARY)
    data = bytearray(fmu.read_bytes())
    start = info.header_offset + 30 + len(info.filename.encode()) + len(info.extra)
    data[start : start + 64] = b"\xff" * 64  # not a valid deflate block
    fmu.write_bytes(bytes(data))
    refused(fmu, rf"member '{LIBRARY}' cannot be extracted \(.*\); the archive is damaged")
    assert extracted_nothing(temp_root)


# ------------------------------------------------------------------------ odd members


@pytest.mark.parametrize(
    ("fields", "pattern"),
    [
        ({"flags": 0x1}, r"member 'resources/m\.bin' is encrypted; an FMU must be readable"),
        (
            {"method": zipfile.ZIP_BZIP2},
            r"compression method 12; the FMI standard allows only "
            r"stored and deflate",
        ),
        ({"method": zipfile.ZIP_LZMA}, r"compression method 14"),
        ({"method": 93}, r"compression method 93"),  # zstd, unknown to zipfile
    ],
    ids=["encrypted", "bzip2", "lzma", "zstd"],
)
def test_encrypted_or_non_fmi_compression_is_refused(
    whitebox_fmu: Path, tmp_path: Path, temp_root: Path, fields: dict, pattern: str
) -> None:
    fmu = rewrite(whitebox_fmu, tmp_path / "odd.fmu", add=[(stored("resources/m.bin"), b"z" * 99)])
    refused(patch_central(fmu, "resources/m.bin", **fields), pattern)
    assert extracted_nothing(temp_root)


def test_duplicate_member_is_refused(whitebox_fmu: Path, tmp_path: Path, temp_root: Path) -> None:
    with pytest.warns(UserWarning, match="Duplicate name"):
        fmu = rewrite(
            whitebox_fmu,
            tmp_path / "twice.fmu",
            add=[(zipfile.ZipInfo("modelDescription.xml"), b"<other/>")],
        )
    refused(fmu, r"member 'modelDescription\.xml' appears twice; tools disagree")
    assert extracted_nothing(temp_root)


@pytest.mark.parametrize(
    "name",
    [
        "..\\evil.txt",
        "resources\\..\\..\\evil.txt",
        "C:/evil.txt",
        "C:evil.txt",
        "//server/share/evil.txt",
    ],
)
def test_windows_style_escapes_are_refused(
    whitebox_fmu: Path, tmp_path: Path, temp_root: Path, name: str
) -> None:
    fmu = rewrite(whitebox_fmu, tmp_path / "win.fmu", add=[(zipfile.ZipInfo(name), b"owned")])
    refused(fmu, "would be written outside the extraction folder")
    assert extracted_nothing(temp_root)


@pytest.mark.parametrize(
    ("make", "pattern"),
    [
        (lambda p, fmu: p.write_bytes(b""), "not a zip archive"),
        (
            lambda p, fmu: p.write_bytes(fmu.read_bytes()[: len(fmu.read_bytes()) // 2]),
            "not a zip archive",
        ),
        (lambda p, fmu: p.mkdir(), "a folder, not an FMU file; give the .fmu archive"),
    ],
    ids=["empty file", "truncated", "folder"],
)
def test_empty_truncated_or_folder(
    whitebox_fmu: Path, tmp_path: Path, temp_root: Path, make, pattern: str
) -> None:
    path = tmp_path / "model.fmu"
    make(path, whitebox_fmu)
    refused(path, pattern)
    assert extracted_nothing(temp_root)


# ------------------------------------------------------------------------ binaries


@pytest.mark.parametrize(
    ("library", "reason"),
    [
        (b"\x7fELF not really", "file too short|invalid ELF header"),
        (Path(_ctypes.__file__).read_bytes(), "undefined symbol|has no attribute"),
    ],
    ids=["not a shared library", "no FMI functions"],
)
def test_binary_that_does_not_load_is_an_archive_error(
    whitebox_fmu: Path, tmp_path: Path, library: bytes, reason: str
) -> None:
    fmu = rewrite(whitebox_fmu, tmp_path / "bad_binary.fmu", replace={LIBRARY: library})
    cwd = Path.cwd()
    with open_fmu(fmu) as archive, pytest.raises(FmuArchiveError) as info:
        FmuInstance(archive, [], ["ram_position"])
    message = str(info.value)
    assert message.startswith(f"{fmu}: its binary for {fmpy_platform} cannot be loaded")
    assert f"re-export the FMU for {fmpy_platform}" in message
    assert any(part in message for part in reason.split("|")), message
    assert Path.cwd() == cwd  # fmpy had changed into the (now deleted) binary folder


def test_model_description_of_another_build_is_refused_at_instantiation(
    whitebox_fmu: Path, tmp_path: Path
) -> None:
    xml = archive_tests.description(whitebox_fmu)
    start = xml.index(b'guid="{') + 7
    forged = xml[:start] + b"00000000" + xml[start + 8 :]
    fmu = rewrite(whitebox_fmu, tmp_path / "guid.fmu", replace={"modelDescription.xml": forged})
    with open_fmu(fmu) as archive, pytest.raises(FmuError) as info:
        FmuInstance(archive, [], ["ram_position"])
    assert (info.value.call, info.value.status) == ("fmi2Instantiate", "NULL")
    assert "this binary's" in str(info.value)
    assert "the modelDescription.xml belongs to another build or export" in str(info.value)


# ------------------------------------------------------------------------ XML tricks


def with_doctype(xml: bytes, doctype: bytes, entity: bytes) -> bytes:
    """``xml`` with a DOCTYPE after the declaration and ``entity`` used in the description."""
    head, _, body = xml.partition(b"?>")
    return head + b"?>" + doctype + body.replace(b'description="', b'description="' + entity, 1)


def test_external_entity_is_not_resolved(whitebox_fmu: Path, tmp_path: Path, temp_root) -> None:
    secret = tmp_path / "secret.txt"
    secret.write_text("password")
    doctype = f'<!DOCTYPE x [<!ENTITY leak SYSTEM "file://{secret}">]>'.encode()
    xml = with_doctype(archive_tests.description(whitebox_fmu), doctype, b"&leak;")
    fmu = rewrite(whitebox_fmu, tmp_path / "xxe.fmu", replace={"modelDescription.xml": xml})
    error = refused(fmu, r"unreadable modelDescription\.xml: .*leak.*re-export the FMU")
    assert "password" not in str(error)
    assert extracted_nothing(temp_root)


def test_entity_expansion_bomb_is_refused(whitebox_fmu: Path, tmp_path: Path, temp_root) -> None:
    levels = "".join(f'<!ENTITY e{i} "{f"&e{i - 1};" * 10}">' for i in range(1, 10))
    doctype = f'<!DOCTYPE x [<!ENTITY e0 "lol">{levels}]>'.encode()
    xml = with_doctype(archive_tests.description(whitebox_fmu), doctype, b"&e9;")
    fmu = rewrite(whitebox_fmu, tmp_path / "laughs.fmu", replace={"modelDescription.xml": xml})
    refused(fmu, r"unreadable modelDescription\.xml: .*amplification")
    assert extracted_nothing(temp_root)


# ------------------------------------------------------------------------ properties

member_names = st.lists(
    st.sampled_from(["..", ".", "", "a", "resources", "C:", "\\", "..\\x", "/", "~", "%2e%2e"]),
    min_size=1,
    max_size=5,
).map("/".join)


@FUZZ
@given(name=member_names)
def test_random_member_names_never_escape(
    whitebox_fmu: Path, tmp_path_factory: pytest.TempPathFactory, name: str
) -> None:
    """Whatever the member name, open_fmu refuses it or extracts it inside its own folder."""
    root = tmp_path_factory.mktemp("names")
    inside = root / "deep" / "er"
    inside.mkdir(parents=True)
    fmu = rewrite(whitebox_fmu, inside / "m.fmu", add=[(zipfile.ZipInfo(name), b"payload")])
    before = sorted(root.rglob("*"))
    try:
        with open_fmu(fmu) as archive:
            written = [p for p in archive.unzip_dir.rglob("*") if p.is_file()]
            assert all(p.resolve().is_relative_to(archive.unzip_dir.resolve()) for p in written)
    except FmuArchiveError as error:
        assert str(fmu) in str(error)
    assert sorted(root.rglob("*")) == before


@FUZZ
@given(data=st.data())
def test_random_byte_damage_gives_only_archive_errors(
    whitebox_fmu: Path, tmp_path_factory: pytest.TempPathFactory, data: st.DataObject
) -> None:
    """Flip bytes anywhere: the FMU opens (harmless spot) or gives an FmuArchiveError."""
    content = bytearray(whitebox_fmu.read_bytes())
    for _ in range(data.draw(st.integers(1, 4))):
        at = data.draw(st.integers(0, len(content) - 1))
        content[at] ^= data.draw(st.integers(1, 255))
    fmu = tmp_path_factory.mktemp("flip") / "flipped.fmu"
    fmu.write_bytes(bytes(content))
    try:
        open_fmu(fmu).close()
    except FmuArchiveError as error:
        assert str(fmu) in str(error)
