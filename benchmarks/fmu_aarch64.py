"""The aarch64-linux plant FMU stepped in qemu-aarch64 against the x86-64 one, both cross-compiled by zig cc
from the same sources and stepped by ``fmu/c/harness/step_fmi3.c`` (a minimal FMI 3 importer in C).

Needs Debian's ``qemu-user`` and ``libc6-arm64-cross`` (``apt-get install qemu-user libc6-arm64-cross``),
which is why it is a benchmark and not a test. Prints both results and their largest relative
difference (clang may contract a*b+c into an FMA on aarch64; measured 4e-16 after 50 steps).

    python benchmarks/fmu_aarch64.py [--steps 50]
"""
from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from doubles import identification  # noqa: E402
from fmpy import read_model_description  # noqa: E402

from qomni.datasheet import DataSheet  # noqa: E402
from qomni.fmu.build import c_source_directory  # noqa: E402
from qomni.fmu.cosim import MOTOR_TORQUE  # noqa: E402
from qomni.fmu.export import export_plant_fmu  # noqa: E402
from qomni.fmu.platforms import PLATFORMS, zig_cc  # noqa: E402

SYSROOT = Path("/usr/aarch64-linux-gnu")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=50)
    args = parser.parse_args()
    if shutil.which("qemu-aarch64") is None or not (SYSROOT / "lib").is_dir():
        print("needs qemu-aarch64 and an aarch64 glibc: apt-get install qemu-user libc6-arm64-cross")
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        fmu = export_plant_fmu(identification(), DataSheet.load(), tmp / "plant3.fmu", 3,
                               platforms=("x86_64-linux", "aarch64-linux"))
        md = read_model_description(str(fmu))
        vr = {v.name: v.valueReference for v in md.modelVariables}
        with zipfile.ZipFile(fmu) as zf:
            zf.extractall(tmp / "fmu")
        inputs = ",".join(f"{vr[name]}=2.0" for name in MOTOR_TORQUE)
        outputs = ",".join(str(vr[name]) for name in ("x_w", "x_ch_dot", "motor_position.fl"))
        harness = c_source_directory() / "harness" / "step_fmi3.c"
        results = {}
        for target, run in (("x86_64-linux", []), ("aarch64-linux", ["qemu-aarch64", "-L", str(SYSROOT)])):
            exe = tmp / f"step_{target}"
            subprocess.run([*zig_cc(), "-target", PLATFORMS[target].zig_target, "-std=c99", "-O2",
                            f"-I{c_source_directory() / 'include'}", str(harness), "-o", str(exe), "-ldl"],
                           check=True, capture_output=True, cwd=tmp)
            binary = tmp / "fmu" / "binaries" / target / "plant3.so"
            proc = subprocess.run([*run, str(exe), str(binary), md.guid, str(args.steps), "0.002", inputs,
                                   outputs], capture_output=True, text=True, timeout=300)
            if proc.returncode:
                print(f"{target}: {proc.stderr.strip()}")
                return 1
            results[target] = np.array([float(x) for x in proc.stdout.split()])
            print(f"{target:14s} x_w, x_ch_dot, motor_position.fl = {results[target]}")
    a, b = results["aarch64-linux"], results["x86_64-linux"]
    rel = float(np.max(np.abs(a - b) / np.maximum(np.abs(b), 1e-300)))
    print(f"largest relative difference aarch64 vs x86-64: {rel:.2e}")
    return 0 if rel <= 1e-12 else 1


if __name__ == "__main__":
    sys.exit(main())
