"""The platforms an FMU's binaries are built for, and the cross-compiler that builds them from the same
sources: ``zig cc`` of the ``ziglang`` package (Clang with the C libraries of every target: a chosen glibc
version for Linux, MinGW-w64 for Windows), so one toolchain from the package index builds all of them on
any host.

Platform directories follow FMI 3.0 §2.5.1.1 (platform tuple ``<arch>-<sys>``) and FMI 2.0 §2.3
(``linux64``, ``win64``; FMI 2 names no aarch64 directory, the FMI 3 tuple ``aarch64-linux`` is used as
the Reference FMUs do). The Linux binaries are linked against glibc 2.17 (:data:`GLIBC_BASELINE`: RHEL 7,
Ubuntu 14.04 and everything newer); the generated code calls no libm function that glibc versioned later
(:class:`qomni.fmu.codegen.ProductPowerPrinter`).
"""
from __future__ import annotations

import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

GLIBC_BASELINE = "2.17"
"""The oldest glibc the Linux binaries load on (symbol versions <= GLIBC_2.17)."""


class PlatformError(RuntimeError):
    """Cross-compiling failed: unknown platform, ``ziglang`` not installed, or a compiler error."""


@dataclass(frozen=True)
class Platform:
    """One target platform.

    Attributes:
        tuple: FMI 3 platform tuple, also the FMI 3 binaries directory (``x86_64-linux``).
        fmi2_directory: the FMI 2 binaries directory (``linux64``).
        zig_target: ``zig cc -target`` (architecture, OS, C library and its version).
        extension: of the shared library (``.so``, ``.dll``).
    """

    tuple: str
    fmi2_directory: str
    zig_target: str
    extension: str

    def directory(self, fmi_version: int) -> str:
        """The directory under ``binaries/`` for FMI ``fmi_version`` (2 or 3)."""
        return self.fmi2_directory if fmi_version == 2 else self.tuple


PLATFORMS: dict[str, Platform] = {p.tuple: p for p in (
    Platform("x86_64-linux", "linux64", f"x86_64-linux-gnu.{GLIBC_BASELINE}", ".so"),
    Platform("aarch64-linux", "aarch64-linux", f"aarch64-linux-gnu.{GLIBC_BASELINE}", ".so"),
    Platform("x86_64-windows", "win64", "x86_64-windows-gnu", ".dll"),
)}
"""The platforms :func:`cross_compile` builds for, by FMI 3 platform tuple."""

NATIVE = PLATFORMS["x86_64-linux"]
"""The platform of the native build (gcc on this host)."""


def platform(name: str) -> Platform:
    """The :class:`Platform` of an FMI 3 platform tuple. Raises PlatformError for an unknown one."""
    try:
        return PLATFORMS[name]
    except KeyError:
        raise PlatformError(f"unknown platform {name!r}; known: {', '.join(PLATFORMS)}") from None


def zig_cc() -> list[str]:
    """The command of ``zig cc`` from the ``ziglang`` package. Raises PlatformError when it is missing."""
    try:
        import ziglang  # noqa: F401
    except ImportError:
        raise PlatformError("cross-compiling needs the ziglang package (pip install ziglang)") from None
    return [sys.executable, "-m", "ziglang", "cc"]


def cross_compile(target: Platform, source_dir: Path, c_files: list[str], output: Path,
                  timeout: float = 900.0) -> None:
    """Compile ``c_files`` (in ``source_dir``) into the shared library ``output`` for ``target`` with
    ``zig cc -target <zig_target> -std=c99 -shared -fPIC -O2 -fvisibility=hidden -g0`` (only the FMI
    functions exported). Side files of the linker (Windows import library, PDB) stay in a scratch folder.
    The first build for a target also builds its C library into zig's cache (minutes for Windows).

    Raises:
        PlatformError: ``ziglang`` missing, compilation failed or timed out (message has its output).
    """
    output.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="qomni_zig_") as scratch:
        built = Path(scratch) / output.name
        cmd = [*zig_cc(), "-target", target.zig_target, "-std=c99", "-shared", "-fPIC", "-O2", "-g0",
               "-fvisibility=hidden", f"-I{source_dir}", *[str(source_dir / f) for f in c_files],
               "-o", str(built)]
        if target.extension == ".so":
            cmd.append("-lm")
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, cwd=scratch, timeout=timeout)
        except subprocess.TimeoutExpired:
            raise PlatformError(f"zig cc for {target.tuple} took more than {timeout:.0f} s") from None
        if proc.returncode != 0:
            raise PlatformError(f"zig cc for {target.tuple} failed ({' '.join(cmd)}):\n{proc.stderr}")
        output.write_bytes(built.read_bytes())


__all__ = ["GLIBC_BASELINE", "PlatformError", "Platform", "PLATFORMS", "NATIVE", "platform", "zig_cc",
           "cross_compile"]
