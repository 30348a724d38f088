"""``bench.edge_scaling``'s options refused before any work: a fleet run takes minutes, and an
option it cannot use must not cost them."""

from __future__ import annotations

import inspect
import re
import sys

import pytest

import bench.edge_scaling as edge_scaling


@pytest.mark.parametrize("given", ["loop_closing=false", ":=1", "loop_closing:=",
                                   "9lives:=1"])
def test_an_edge_parameter_not_written_name_colon_equals_value_is_refused_before_recording(
        given: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    recorded: list[object] = []
    monkeypatch.setattr(edge_scaling, "record", lambda folder: recorded.append(folder))
    monkeypatch.setattr(sys, "argv", ["edge_scaling", "--devices", "2",
                                      "--edge-param", "restore_keyframes:=0",
                                      "--edge-param", given])
    with pytest.raises(SystemExit) as exited:
        edge_scaling.main()
    assert exited.value.code == 2 and not recorded
    assert "--edge-param: NAME:=VALUE" in capsys.readouterr().err


@pytest.mark.parametrize(("given", "says"), [("devices:=[ar1]", "(its --devices)"),
                                            ("loop_worker_share:=0.5", "--loop-worker-share"),
                                            ("vmax_total:=90", "the bench sets it")])
def test_an_edge_parameter_the_bench_sets_itself_is_refused_with_the_option_that_does(
        given: str, says: str, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(edge_scaling, "record", lambda folder: pytest.fail("recorded"))
    monkeypatch.setattr(sys, "argv", ["edge_scaling", "--edge-param", given])
    with pytest.raises(SystemExit) as exited:
        edge_scaling.main()
    assert exited.value.code == 2 and says in capsys.readouterr().err


@pytest.mark.parametrize("given", ["loop_closing:=false", "restore_keyframes:=0",
                                   "qos_overrides./tf.depth:=5"])
def test_an_edge_parameter_as_ros_takes_it_is_accepted(given: str) -> None:
    assert edge_scaling.EDGE_PARAM.fullmatch(given)
    assert given.split(":=")[0] not in edge_scaling.BENCH_SETS


def test_every_parameter_the_bench_hands_an_edge_is_one_edge_param_refuses() -> None:
    """The refusal's list and the edge's command line name the same parameters: one the bench
    starts setting must be refused too, or a second value would silently win or lose."""
    source = inspect.getsource(edge_scaling.measure)
    set_by_bench = set(re.findall(r'"([a-z_]+):=', source)) - {"__node"}   # a remap, not -p
    assert set_by_bench == set(edge_scaling.BENCH_SETS)
