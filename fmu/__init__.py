"""FMU export of the identified model: native C Co-Simulation FMUs (FMI 2.0 and 3.0) that run without
Python in any importer.

* :mod:`.spec` -- :class:`~.spec.ModelSpec`, what the generic build needs of one model;
  :mod:`.feedforward_spec` (the law (21)), :mod:`.plant_spec` (the identified vehicle) and
  :mod:`.plant_can_spec` (the vehicle behind its CAN bus, an FMI-LS-BUS CAN terminal) are the specs;
* :mod:`.variables` -- FMU variables, their units and numbering;
* :mod:`.codegen` -- C99 code of the feed-forward law (21) with its exact partial derivatives and of the
  plant's forward dynamics (19)/(20), generated with sympy from :mod:`qomni.ident.symbolic`;
* :mod:`.description` -- modelDescription.xml (FMI 2 and 3) and FMI 3's buildDescription.xml;
* :mod:`.build` -- config.h, the binaries and the zip;
* :mod:`.platforms` -- the target platforms and their cross-compilation with ``zig cc`` (package ziglang);
* :mod:`.export` -- :func:`~.export.export_fmu` of any spec, ``export_plant_fmu``, ``export_feedforward_fmu``,
  ``export_plant_can_fmu``;
* :mod:`.plant_reference` -- the plant's hybrid model in numpy (the rules, and the tests' reference);
* :mod:`.cosim` -- fmpy helpers: :class:`~.cosim.PlantVehicle` (the plant as a vehicle for the
  campaign controller) and the closed-loop co-simulation of the campaign;
* :mod:`.lsbus` -- FMI-LS-BUS CAN operations and :class:`~.lsbus.CanBusSlave`, the plant-can FMU driven at
  its bus terminal in fmpy;
* :mod:`.parameter_sets` -- parameter sets sampled from the identified covariance, as an SSP archive;
* :mod:`.accuracy` -- windowed prediction errors of the plant FMU on a recorded campaign;
* ``fmu/c`` -- the generic FMI 2/3 C layer (``fmi2Functions.c``, ``fmi3Functions.c``,
  ``fmu_instance.c``, ``fmu_state.c``), the FMI headers and the per-model C code (``feedforward/``, ``plant/``,
  ``plant_can/``).

``fmu`` depends on ``ident`` only (never on ``emulator``).
"""
