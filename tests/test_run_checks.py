"""A live run's bad options are refused with the reason before any node starts: a parameter
file that is no parameter mapping, an unknown policy, a learned policy without its checkpoint
— for ``twinslam launch`` as for ``twinslam evaluate``."""

from __future__ import annotations

from pathlib import Path

import pytest

from twinslam.cli.main import main
from twinslam.live.launcher import DEFAULT_PARAMS, PAPER_PARAMS
from twinslam.live.run_checks import params_file_problem, policy_problem


@pytest.mark.parametrize(("text", "says"), [
    ("just a string\n", "its top level is a str"),
    ("- a\n- list\n", "its top level is a list"),
    ("edge_mapper: 3\n", "'edge_mapper' must hold a ros__parameters mapping"),
    ("edge_mapper:\n  ros__parameters: [1, 2]\n", "must hold a ros__parameters mapping"),
    ("edge_mapper: {ros__parameters: {policy: lff}\n", "is not YAML"),
])
def test_a_parameter_file_that_is_not_a_parameter_mapping_is_refused_with_the_reason(
        tmp_path: Path, text: str, says: str) -> None:
    bad = tmp_path / "params.yaml"
    bad.write_text(text, encoding="utf-8")
    problem = params_file_problem(bad)
    assert problem is not None and says in problem, problem


@pytest.mark.parametrize("key", ["edge_mapper", "/edge_mapper", "/**/edge_mapper",
                                 "/ar1/edge_mapper"])
def test_a_parameter_a_twinslam_node_does_not_have_is_refused_with_the_likely_one(
        tmp_path: Path, key: str) -> None:
    """A misspelt name would leave the node on its default without a word: refused before
    any node starts, in whichever section of the node it stands."""
    bad = tmp_path / "params.yaml"
    bad.write_text(f"{key}:\n  ros__parameters:\n    vmax: 20\n    vmaxx: 30\n",
                   encoding="utf-8")
    problem = params_file_problem(bad)
    assert problem is not None and "edge_mapper has no parameter 'vmaxx' (did you mean vmax?)" \
        in problem, problem


def test_sections_for_every_node_or_for_other_nodes_and_rclpys_own_are_not_checked(
        tmp_path: Path) -> None:
    ok = tmp_path / "params.yaml"
    ok.write_text("/**:\n  ros__parameters:\n    log_every: 3\n"
                  "camera_driver:\n  ros__parameters:\n    exposure: 8\n"
                  "device_tracker:\n  ros__parameters:\n    use_sim_time: true\n"
                  "    qos_overrides./tf.publisher.depth: 10\n    slot_frames: 60\n",
                  encoding="utf-8")
    assert params_file_problem(ok) is None


def test_the_bundled_files_an_empty_one_and_a_missing_one() -> None:
    assert params_file_problem(DEFAULT_PARAMS) is None
    assert params_file_problem(PAPER_PARAMS) is None
    assert "does not exist" in str(params_file_problem(Path("/no/such/params.yaml")))


def test_policies_the_edge_cannot_run_are_named() -> None:
    for ok in ("lff", "pu", "adapt", "random", "mpc:H=2", "delay:0.3:lff"):
        assert policy_problem(ok) is None, ok
    assert "unknown policy 'bogus'" in str(policy_problem("bogus"))
    assert "mbrl:CHECKPOINT" in str(policy_problem("mbrl"))
    assert "no such policy checkpoint" in str(policy_problem("mbrl:/no/such.pt"))


@pytest.mark.parametrize("command", ["launch", "evaluate"])
def test_launch_and_evaluate_refuse_before_any_node_starts(
        command: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Exit 2 with one line naming the option — no node started, nothing written."""
    bad = tmp_path / "params.yaml"
    bad.write_text("just a string\n", encoding="utf-8")
    out = tmp_path / "out"
    common = ["--sequence", "synthetic:20", "--frames", "10", "--out", str(out)]
    assert main([command, *common, "--params", str(bad)]) == 2
    assert "--params: parameter file" in capsys.readouterr().err
    assert main([command, *common, "--policy", "lff,bogus"]) == 2
    err = capsys.readouterr().err
    assert "--policy: policy 'bogus': unknown policy" in err and "Traceback" not in err
    assert not out.exists()
