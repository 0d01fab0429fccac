"""Many machines, locally: a Ray cluster of a head and a worker node (``ray.cluster_utils``), via ``--address``.

Each node offers one CPU and the study asks for two workers, so the two long-lived workers land on
different nodes; the driver runs as its own process (``autotune launch --address``), as it would on
a laptop next to a cluster. The cluster keeps running after the study; stopping it ends every
process it started (the test's environment tag finds them).
"""

from __future__ import annotations

import uuid
from pathlib import Path

import optuna
import pytest

from tests.test_search_launch import check_finished_trials, finish, launch, load, tagged_processes, write_spec


def test_smoke_study_on_a_two_node_cluster(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from ray.cluster_utils import Cluster

    tag = uuid.uuid4().hex
    monkeypatch.setenv("AUTOTUNE_TEST_TAG", tag)  # the cluster's processes inherit it
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
    try:
        cluster.add_node(num_cpus=1)
        cluster.wait_for_nodes()
        spec = write_spec(tmp_path, "cluster", study={"n_trials": 3, "pruner": "none"}, resources={"workers": 2})
        rc, out, err = finish(launch(tmp_path, str(spec), "--address", cluster.address, tag=tag), 300)
        assert rc == 0, err[-3000:]
        study = load(tmp_path, "cluster")
        check_finished_trials(study)
        assert [t.state for t in study.trials] == [optuna.trial.TrialState.COMPLETE] * 3
        assert len({t.user_attrs["ray_node"] for t in study.trials}) == 2  # both nodes ran trials
        assert not (tmp_path / "runs" / "cluster" / "ray").exists()  # a joined cluster is not ours to record
    finally:
        cluster.shutdown()
    assert tagged_processes(tag) == []
