"""The blind suite (``qomni.suite``) under its earlier name: cases, runner and scoring in one namespace."""
from qomni.suite.cases import (MAGNITUDES, PROTOTYPE_OWN, TABLE, VEHICLES, Case, draw, draw_cases,  # noqa: F401
                               effect_name, effects_toml, range_position, variant)
from qomni.suite.runner import (REFERENCES, ideal_reference, probe_case, reference_run, run_campaign,  # noqa: F401
                                run_case, run_suite)
from qomni.suite.scoring import (CaseResult, excess_shrink, noise_floor, read_results, read_run,  # noqa: F401
                                 score, write_results)
