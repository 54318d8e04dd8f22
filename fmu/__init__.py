"""FMU export of the identified model: native C Co-Simulation FMUs (FMI 2.0 and 3.0) that run without
Python in any importer.

* :mod:`fmu.codegen` -- C99 code of the feed-forward law (21) and of the plant's forward dynamics
  (19)/(20), generated with sympy from :mod:`ident.symbolic`;
* :mod:`fmu.export` -- :func:`fmu.export.export_plant_fmu` and :func:`fmu.export.export_feedforward_fmu`
  build the ``.fmu`` (modelDescription, sources, gcc-compiled binary);
* :mod:`fmu.plant_reference` -- the plant's hybrid model in numpy (the rules, and the tests' reference);
* :mod:`fmu.cosim` -- fmpy helpers: :class:`fmu.cosim.PlantVehicle` (the plant as a vehicle for the
  campaign controller) and the closed-loop co-simulation of the campaign;
* :mod:`fmu.accuracy` -- windowed prediction errors of the plant FMU on a recorded campaign;
* ``fmu/c`` -- the generic FMI 2/3 C layer (``fmi2Functions.c``, ``fmi3Functions.c``,
  ``fmu_instance.c``), the FMI headers and the per-model C code (``feedforward/``, ``plant/``).

``fmu`` depends on ``ident`` only (never on ``emulator``).
"""
