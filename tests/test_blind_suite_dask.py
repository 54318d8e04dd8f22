"""The blind suite on a real Dask cluster bound to 127.0.0.1: tasks run in the workers (each its own
PyBullet client, the case's seed), results come back to the driver, every listening socket is on the
loopback, and a suite started again resumes from its results file."""
from __future__ import annotations

import os

import psutil
import pytest
from distributed import Client, LocalCluster

from qomni.blind_suite import Case, probe_case, read_results, run_suite

CASES = [Case("probe-ideal", {}, [], seed=101),
         Case("probe-payload", {"payload": {"mass": 150.0, "com_offset": [0.1, 0.0]}}, ["payload"], seed=102),
         Case("probe-delay", {"actuator_delay": {"delay": 0.004}}, ["actuator_delay"], seed=103)]


def _listening(pids: set[int]):
    return [c for c in psutil.net_connections(kind="inet") if c.status == psutil.CONN_LISTEN and c.pid in pids]


def test_the_suite_runs_on_a_local_dask_cluster_bound_to_the_loopback(tmp_path):
    with LocalCluster(host="127.0.0.1", n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        me = psutil.Process()
        sockets = _listening({me.pid} | {p.pid for p in me.children(recursive=True)})
        assert sockets and all(c.laddr.ip == "127.0.0.1" for c in sockets), sockets
        results = run_suite(CASES, tmp_path, executor=client.get_executor(), results_path=tmp_path / "r.json",
                            runner=probe_case)
    assert sorted(r.case.name for r in results) == sorted(c.name for c in CASES)
    assert not [r.error for r in results if r.error]
    for r in results:
        assert f"seed {r.case.seed} " in r.verdict                        # the case's own seed
        assert f"pid {os.getpid()}:" not in r.verdict                     # ran in a worker, not the driver
    assert sorted(r.case.name for r in read_results(tmp_path / "r.json")) == sorted(c.name for c in CASES)


def test_a_suite_started_again_runs_only_the_cases_it_has_no_result_for(tmp_path):
    path = tmp_path / "r.json"
    first = run_suite(CASES[:2], tmp_path, workers=1, results_path=path, runner=probe_case)
    assert len(first) == 2

    again = run_suite(CASES, tmp_path, workers=1, results_path=path, runner=_Runner())
    assert sorted(r.case.name for r in again) == sorted(c.name for c in CASES)
    assert not [r.error for r in again if r.error]


class _Runner:
    """A picklable runner that refuses the cases already in the results file (they must be resumed)."""

    def __call__(self, case, work, reference, quick):
        if case.name != "probe-delay":
            raise AssertionError(f"{case.name} ran again")
        return probe_case(case, work, reference, quick)


@pytest.fixture(autouse=True)
def _no_dask_config_leak(monkeypatch, tmp_path):
    monkeypatch.setenv("DASK_TEMPORARY_DIRECTORY", str(tmp_path))
