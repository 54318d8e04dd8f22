"""FMU export of the identified model: native C Co-Simulation FMUs (FMI 2.0 and 3.0) that run without
Python in any importer.

* :mod:`fmu.codegen` -- C99 code of the feed-forward law (21), generated with sympy from
  :mod:`ident.symbolic`;
* :mod:`fmu.export` -- :func:`fmu.export.export_feedforward_fmu` builds the ``.fmu`` (modelDescription,
  sources, gcc-compiled binary);
* ``fmu/c`` -- the generic FMI 2/3 C layer (``fmi2Functions.c``, ``fmi3Functions.c``,
  ``fmu_instance.c``), the FMI headers and the per-model C code (``feedforward/``).

``fmu`` depends on ``ident`` only (never on ``emulator``).
"""
