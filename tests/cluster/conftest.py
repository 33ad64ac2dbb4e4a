"""Fixtures of the cluster tests: a local single-node Slurm (see slurm.py), one for the session."""

import os

import pytest

from .slurm import CLIENT_ENV_PREFIXES, SlurmCluster, local_slurm, missing_reason


@pytest.fixture(scope="session")
def slurm_cluster() -> SlurmCluster:
    """munged, slurmctld and slurmd started for the session and stopped after it; skipped where the
    binaries are missing (``make system-deps-slurm``) or the tests do not run as root."""
    reason = missing_reason()
    if reason:
        pytest.skip(reason)
    with local_slurm() as cluster:
        yield cluster


@pytest.fixture
def slurm_environ(slurm_cluster, monkeypatch) -> SlurmCluster:
    """``os.environ`` pointing at the local cluster for one test, for libraries that call the Slurm
    commands themselves (submitit): ``SLURM_CONF`` set, the caller's other Slurm client variables
    removed; all restored afterwards."""
    for key in list(os.environ):
        if key.startswith(CLIENT_ENV_PREFIXES):
            monkeypatch.delenv(key)
    monkeypatch.setenv("SLURM_CONF", str(slurm_cluster.conf))
    return slurm_cluster
