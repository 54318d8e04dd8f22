"""Binaries for every platform from the same sources: the native build needs nothing newer than glibc 2.17
(no pow@GLIBC_2.29), and zig cc cross-compiles x86_64-linux (glibc 2.17), aarch64-linux and x86_64-windows;
every FMU passes fmpy's validation, the Windows DLL exports every FMI function, the cross-compiled linux
x86-64 binary steps in fmpy like the native one (the aarch64 one steps in qemu-aarch64:
``python benchmarks/fmu_aarch64.py``, which needs Debian's qemu-user and libc6-arm64-cross)."""
import re
import shutil
import subprocess
import zipfile

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")
pytest.importorskip("ziglang")
from fmpy.validation import validate_fmu  # noqa: E402

from qomni.datasheet import DataSheet  # noqa: E402
from qomni.fmu.cosim import MOTOR_TORQUE, FmuSlave  # noqa: E402
from qomni.fmu.export import FmuExportError, export_feedforward_fmu, export_plant_fmu  # noqa: E402
from qomni.fmu.platforms import GLIBC_BASELINE, PLATFORMS  # noqa: E402
from doubles import identification  # noqa: E402

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None or shutil.which("objdump") is None,
                                reason="needs gcc and objdump (binutils)")

SHEET = DataSheet.load()
FMI_FUNCTIONS = {2: ("fmi2Instantiate", "fmi2DoStep", "fmi2GetReal", "fmi2SetReal", "fmi2SerializeFMUstate",
                     "fmi2GetDirectionalDerivative", "fmi2FreeInstance"),
                 3: ("fmi3InstantiateCoSimulation", "fmi3DoStep", "fmi3GetFloat64", "fmi3SetFloat64",
                     "fmi3SerializeFMUState", "fmi3GetDirectionalDerivative", "fmi3FreeInstance")}


@pytest.fixture(scope="session")
def cross_fmus(tmp_path_factory):
    """The plant for every platform, FMI 2 and 3 (the first Windows build fills zig's cache: minutes)."""
    d = tmp_path_factory.mktemp("cross")
    return {v: export_plant_fmu(identification(), SHEET, d / f"plant{v}.fmu", v, platforms=tuple(PLATFORMS))
            for v in (2, 3)}


@pytest.fixture(scope="session")
def native_fmus(tmp_path_factory):
    d = tmp_path_factory.mktemp("native")
    return {(kind, v): export(identification(), SHEET, d / f"{kind}{v}.fmu", v)
            for kind, export in (("plant", export_plant_fmu), ("feedforward", export_feedforward_fmu))
            for v in (2, 3)}


def _glibc_versions(binary) -> set[tuple[int, ...]]:
    text = subprocess.run(["objdump", "-T", str(binary)], capture_output=True, text=True, check=True).stdout
    return {tuple(int(x) for x in m.split(".")) for m in re.findall(r"GLIBC_([0-9.]+)\b", text)}


def _extract(fmu, tmp_path):
    with zipfile.ZipFile(fmu) as zf:
        zf.extractall(tmp_path)
    return tmp_path


def test_native_binaries_need_nothing_newer_than_the_glibc_baseline(native_fmus, tmp_path):
    baseline = tuple(int(x) for x in GLIBC_BASELINE.split("."))
    for (kind, v), fmu in native_fmus.items():
        root = _extract(fmu, tmp_path / f"{kind}{v}")
        [binary] = (root / "binaries").rglob("*.so")
        versions = _glibc_versions(binary)
        assert versions and max(versions) <= baseline, (kind, v, sorted(versions))
        for source in (root / "sources").glob("*_generated.c"):
            assert "pow(" not in source.read_text()  # integer powers are products


@pytest.mark.parametrize("version", [2, 3])
def test_cross_compiled_fmus_validate_and_carry_every_platform(cross_fmus, version, tmp_path):
    assert validate_fmu(str(cross_fmus[version])) == []
    root = _extract(cross_fmus[version], tmp_path)
    baseline = tuple(int(x) for x in GLIBC_BASELINE.split("."))
    for target in PLATFORMS.values():
        binary = root / "binaries" / target.directory(version) / f"plant{version}{target.extension}"
        assert binary.is_file(), binary
        head = binary.read_bytes()[:20]
        if target.extension == ".so":
            machine = int.from_bytes(head[18:20], "little")  # ELF e_machine: 62 x86-64, 183 AArch64
            assert head[:4] == b"\x7fELF" and machine == (183 if target.tuple.startswith("aarch64") else 62)
            assert max(_glibc_versions(binary)) <= baseline
        else:
            exports = subprocess.run(["objdump", "-p", str(binary)], capture_output=True, text=True).stdout
            assert head[:2] == b"MZ" and all(re.search(rf"\b{f}\b", exports) for f in FMI_FUNCTIONS[version])


@pytest.mark.parametrize("version", [2, 3])
def test_the_cross_compiled_linux_binary_steps_like_the_native_one(cross_fmus, native_fmus, version):
    results = []
    for fmu in (cross_fmus[version], native_fmus[("plant", version)]):
        with FmuSlave(fmu) as s:
            s.set_real(s.refs(MOTOR_TORQUE), [2.0, 2.0, 2.0, 2.0])
            for _ in range(50):
                s.step(0.002)
            results.append(s.get_real(s.refs(["x_w", "x_ch_dot", "motor_position.fl"])))
    assert results[0][1] > 0.1
    np.testing.assert_allclose(results[0], results[1], rtol=1e-12)  # clang and gcc, the same IEEE arithmetic


def test_an_unknown_platform_is_an_error(tmp_path):
    with pytest.raises(FmuExportError, match="unknown platform 'riscv64-linux'"):
        export_plant_fmu(identification(), SHEET, tmp_path / "p.fmu", 3, platforms=("riscv64-linux",))
