"""The identified uncertainty travels with the model: N parameter sets sampled from the identification's
covariance, packaged with the plant FMU as an SSP archive (Modelica Association SSP 1.0: System Structure
Description ``SystemStructure.ssd``, parameter sets as SSV files, ``application/x-ssp-parameter-set``).

Archive layout (a zip, suffix ``.ssp``)::

    SystemStructure.ssd            one System with the FMU as Component "plant", bound to the nominal set
    resources/<model>.fmu          the FMU the sets are for
    resources/nominal.ssv          the identified values p of (18)
    resources/samples/sample_NNNN.ssv   N sets drawn from N(p1_hat, Sigma_p1) (B_w fixed)

Each SSV ``ParameterSet`` holds the 11 parameters of (18) by the FMU's variable names (``C_l`` ... ``B_w``)
as ``ssv:Real`` with SI units (``ssv:Units``: the FMU's unit names and base units). The sampled p1 is the
multivariate normal of the estimate's covariance (``IdentificationResult.covariance``, order P1_NAMES),
truncated by rejection to the physically admissible region (inertias C_l, C_r, m_ch, C_ch > 0, damping
and Coulomb levels >= 0), which the FMU requires; the sets' annotation records the seed and the
rejection count.
"""
from __future__ import annotations

import io
import os
import tempfile
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np

from qomni.conventions import P1_NAMES, PARAMETER_NAMES

from .variables import UNITS

SSD = "http://ssp-standard.org/SSP1/SystemStructureDescription"
SSV = "http://ssp-standard.org/SSP1/SystemStructureParameterValues"
SSC = "http://ssp-standard.org/SSP1/SystemStructureCommon"
for _prefix, _uri in (("ssd", SSD), ("ssv", SSV), ("ssc", SSC)):
    ET.register_namespace(_prefix, _uri)

#: The FMU's unit of each parameter of (18) (names of :data:`qomni.fmu.variables.UNITS`).
FMU_UNITS = {"C_l": "kg.m2", "d_vl": "N.m.s/rad", "d_cl": "N.m", "C_r": "kg.m2", "d_vr": "N.m.s/rad",
             "d_cr": "N.m", "m_ch": "kg", "C_ch": "kg.m2", "d_vw": "N.m.s/rad", "d_cw": "N.m", "B_w": "kg.m2"}
POSITIVE = ("C_l", "C_r", "m_ch", "C_ch")
"""Parameters that must be > 0 (inertias); the others must be >= 0."""
MAX_DRAWS_PER_SET = 100
"""Rejection sampling gives up (ParameterSetError) after this many draws per accepted set."""


class ParameterSetError(ValueError):
    """No covariance to sample from, an inadmissible request, or a file that is not such a parameter set."""


def sample_parameters(identification, n: int, seed: int = 0) -> tuple[np.ndarray, int]:
    """``n`` parameter vectors p (18) drawn from the identification's uncertainty.

    Args:
        identification: :class:`qomni.ident.result.IdentificationResult` with ``covariance`` (10, 10) of p1.
        n: number of sets (>= 1). seed: numpy Generator seed.
    Returns:
        (samples (n, 11) in PARAMETER_NAMES order, B_w fixed at the identified value; rejected draws).
    Raises:
        ParameterSetError: no covariance, a covariance that is not symmetric positive semi-definite of shape
        (10, 10), n < 1, or fewer than one admissible draw in MAX_DRAWS_PER_SET.
    """
    if not isinstance(n, (int, np.integer)) or n < 1:
        raise ParameterSetError(f"n must be an integer >= 1, got {n!r}")
    cov = getattr(identification, "covariance", None)
    if cov is None:
        raise ParameterSetError("the identification has no covariance of p1 (identification.json without "
                                "'covariance'): nothing to sample from")
    cov = np.asarray(cov, dtype=float)
    if cov.shape != (10, 10) or not np.all(np.isfinite(cov)) or not np.allclose(cov, cov.T, rtol=1e-9, atol=0):
        raise ParameterSetError(f"covariance must be a finite symmetric (10, 10) matrix, got shape {cov.shape}")
    if np.min(np.linalg.eigvalsh(cov)) < -1e-9 * max(np.max(np.diag(cov)), 1e-300):
        raise ParameterSetError("covariance is not positive semi-definite")
    mean = np.array([identification.values[name] for name in P1_NAMES], dtype=float)
    rng = np.random.default_rng(seed)
    accepted: list[np.ndarray] = []
    rejected = 0
    positive = np.array([name in POSITIVE for name in P1_NAMES])
    while len(accepted) < n:
        if rejected > MAX_DRAWS_PER_SET * n:
            raise ParameterSetError(f"only {len(accepted)} of {n} draws admissible after {rejected} rejections: "
                                    "the uncertainty reaches far into negative parameters")
        draws = rng.multivariate_normal(mean, cov, size=n - len(accepted), method="eigh")
        ok = np.all(np.where(positive, draws > 0, draws >= 0), axis=1)
        accepted.extend(draws[ok])
        rejected += int(np.sum(~ok))
    p1 = np.array(accepted[:n])
    return np.column_stack([p1, np.full(n, float(identification.B_w))]), rejected


def parameter_set(name: str, values: dict[str, float], description: str) -> ET.Element:
    """One SSV ParameterSet (SSP 1.0 SystemStructureParameterValues) of ``values`` {FMU name: value}."""
    root = ET.Element(f"{{{SSV}}}ParameterSet", {"version": "1.0", "name": name, "description": description})
    params = ET.SubElement(root, f"{{{SSV}}}Parameters")
    for key, value in values.items():
        if not np.isfinite(value):
            raise ParameterSetError(f"parameter {key} = {value!r} is not finite")
        p = ET.SubElement(params, f"{{{SSV}}}Parameter", name=key)
        ET.SubElement(p, f"{{{SSV}}}Real", value=repr(float(value)), unit=FMU_UNITS[key])
    units = ET.SubElement(root, f"{{{SSV}}}Units")
    for unit in sorted({FMU_UNITS[key] for key in values}):
        u = ET.SubElement(units, f"{{{SSC}}}Unit", name=unit)
        ET.SubElement(u, f"{{{SSC}}}BaseUnit", {k: str(e) for k, e in UNITS[unit].items()})
    return root


def _system(name: str, fmu_name: str) -> ET.Element:
    root = ET.Element(f"{{{SSD}}}SystemStructureDescription", {"version": "1.0", "name": name})
    system = ET.SubElement(root, f"{{{SSD}}}System", name=name)
    elements = ET.SubElement(system, f"{{{SSD}}}Elements")
    component = ET.SubElement(elements, f"{{{SSD}}}Component", {
        "name": "plant", "type": "application/x-fmu-sharedlibrary", "source": f"resources/{fmu_name}"})
    bindings = ET.SubElement(component, f"{{{SSD}}}ParameterBindings")
    ET.SubElement(bindings, f"{{{SSD}}}ParameterBinding",
                  {"type": "application/x-ssp-parameter-set", "source": "resources/nominal.ssv"})
    return root


def _xml(root: ET.Element) -> bytes:
    ET.indent(root, space="  ")
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True) + b"\n"


def sample_name(i: int) -> str:
    """Path in the archive of sample ``i`` (0-based)."""
    return f"resources/samples/sample_{i + 1:04d}.ssv"


def write_parameter_sets(identification, fmu: str | os.PathLike, out: str | os.PathLike, n: int = 100,
                         seed: int = 0) -> Path:
    """Write the SSP archive ``out`` (module docstring) with the FMU ``fmu`` and ``n`` sampled sets.

    Raises:
        ParameterSetError: as :func:`sample_parameters`; ``out`` without the ``.ssp`` suffix; ``fmu`` missing.
    Returns:
        ``out``, written atomically (a temporary file renamed).
    """
    out, fmu = Path(out), Path(fmu)
    if out.suffix != ".ssp":
        raise ParameterSetError(f"out must end with .ssp, got {str(out)!r}")
    if not fmu.is_file():
        raise ParameterSetError(f"FMU {str(fmu)!r} not found")
    samples, rejected = sample_parameters(identification, n, seed)
    nominal = {**{k: float(identification.values[k]) for k in P1_NAMES}, "B_w": float(identification.B_w)}
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".parameter_sets_", suffix=".ssp", dir=out.parent)
    os.close(fd)
    try:
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zf:
            zf.writestr("SystemStructure.ssd", _xml(_system(out.stem, fmu.name)))
            zf.write(fmu, f"resources/{fmu.name}")
            zf.writestr("resources/nominal.ssv", _xml(parameter_set(
                "nominal", nominal, "identified p of (18)")))
            for i, row in enumerate(samples):
                zf.writestr(sample_name(i), _xml(parameter_set(
                    f"sample_{i + 1:04d}", dict(zip(PARAMETER_NAMES, row)),
                    f"draw {i + 1} of {n} from N(p1_hat, Sigma_p1), B_w fixed; seed {seed}, "
                    f"{rejected} inadmissible draws rejected")))
        os.replace(tmp, out)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return out


def read_parameter_sets(path: str | os.PathLike) -> tuple[dict[str, float], np.ndarray]:
    """The nominal set {name: value} and the samples (N, 11) (PARAMETER_NAMES order) of an archive written by
    :func:`write_parameter_sets`. Raises ParameterSetError for a missing set, parameter or non-finite value."""
    def values(zf: zipfile.ZipFile, name: str) -> dict[str, float]:
        try:
            root = ET.parse(io.BytesIO(zf.read(name))).getroot()
        except (KeyError, ET.ParseError) as exc:
            raise ParameterSetError(f"{path}: {name}: {exc}") from None
        out = {}
        for p in root.iter(f"{{{SSV}}}Parameter"):
            real = p.find(f"{{{SSV}}}Real")
            out[p.get("name")] = float(real.get("value")) if real is not None else float("nan")
        missing = [k for k in PARAMETER_NAMES if not np.isfinite(out.get(k, float("nan")))]
        if missing:
            raise ParameterSetError(f"{path}: {name}: missing or non-finite {', '.join(missing)}")
        return out

    try:
        with zipfile.ZipFile(path) as zf:
            nominal = values(zf, "resources/nominal.ssv")
            names = sorted(n for n in zf.namelist() if n.startswith("resources/samples/") and n.endswith(".ssv"))
            samples = np.array([[values(zf, n)[k] for k in PARAMETER_NAMES] for n in names]).reshape(-1, 11)
    except (OSError, zipfile.BadZipFile) as exc:
        raise ParameterSetError(f"{path}: not a parameter-set archive ({exc})") from None
    return nominal, samples


__all__ = ["ParameterSetError", "FMU_UNITS", "sample_parameters", "parameter_set", "sample_name",
           "write_parameter_sets", "read_parameter_sets"]
