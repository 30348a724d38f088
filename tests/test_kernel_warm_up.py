"""The kernels a node loads before its first slot are the ones its slots run.

``make`` compiles the numba kernels once (``twinslam.cli.precompile``) and every node loads
them before it listens (``load_kernels``); a kernel called in a slot with arguments of
another type or memory layout compiles a second overload there, seconds on a fresh checkout,
and that slot's map update is late. A short shared walk in process must add no overload to
any kernel: two devices on the corridor, the second 70 frames behind, its map merged into the
first's at its third slot and lent the first's keyframes (the kernels a 300-frame walk used
are the same six: the synthetic world's, the front end's, the merge's join and the slot
scores).
"""

from __future__ import annotations

import csv
import re
import subprocess
import sys
from pathlib import Path

import pytest

from twinslam.slam.front_end.tracking import TrackingConfig
from twinslam.slot_protocol.lost_frame_rule import MIN_INLIERS

ROOT = Path(__file__).resolve().parents[1]
#: the tests that read the one walk: one worker runs it
ONE_WALK = pytest.mark.xdist_group("shared-walk")

#: load the kernels as a node does, walk, and print every overload the walk added
_WALK = """
import runpy, sys
from numba.core.registry import CPUDispatcher
from twinslam.live.node_fork_server import load_kernels

OURS = ("twinslam", "edge_mapper", "device_tracker", "udt_node")

def overloads():
    found = {}
    for name, module in list(sys.modules.items()):
        if name.split(".")[0] in OURS:
            for value in list(vars(module).values()):
                if isinstance(value, CPUDispatcher):
                    key = f"{value.__module__}.{value.__name__}"
                    found[key] = {str(s) for s in value.signatures}
    return found

load_kernels()
before = overloads()
sys.argv = ["place_walks", "--devices", "2", "--frames", "200", "--after", "70",
            "--frames-csv", sys.argv[1]]
runpy.run_module("bench.place_walks", run_name="__main__")
for kernel, signatures in sorted(overloads().items()):
    for signature in sorted(signatures - before.get(kernel, set())):
        print(f"COMPILED IN A SLOT: {kernel}{signature}")
"""


@pytest.fixture(scope="module")
def shared_walk(tmp_path_factory: pytest.TempPathFactory) -> tuple[str, Path]:
    """The walk's printout, and its frames as the edge served them (``--frames-csv``)."""
    frames = tmp_path_factory.mktemp("walk") / "frames.csv"
    run = subprocess.run([sys.executable, "-c", _WALK, str(frames)], cwd=ROOT,
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    return run.stdout, frames


@pytest.mark.slow(seconds=30)
@ONE_WALK
def test_a_shared_walk_compiles_no_kernel_the_nodes_did_not_load_before_it(
        shared_walk: tuple[str, Path]) -> None:
    printed, _ = shared_walk
    assert "cross-device revisit error" in printed, printed[-2000:]
    compiled = [line for line in printed.splitlines() if line.startswith("COMPILED IN A SLOT")]
    assert not compiled, "\n".join(compiled)


@ONE_WALK
def test_the_walks_frames_are_written_as_the_edge_planned_them(
        shared_walk: tuple[str, Path]) -> None:
    """``--frames-csv``: every frame each device played after its first slot, a row each; a
    frame sharing fewer map points than the device needs is lost by the edge's rule, a covered
    frame is never asked for, and each device's uploads are at least the keyframes it printed
    as integrated (the edge may refuse one)."""
    printed, path = shared_walk
    with path.open(newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    devices = {row["device"] for row in rows}
    assert devices == {"ar1", "ar2"}
    for row in rows:
        if int(row["shared"]) < MIN_INLIERS:
            assert row["lost"] == "1", row
        assert not (row["covered"] == "1" and row["uploaded"] == "1"), row
        assert row["true_x"] != "nan"                 # the corridor has ground truth
        assert int(row["own_keyframes"]) >= 0
        if row["tracked"] == "0":                      # an untracked frame: lost either way
            assert row["lost"] == "1" and row["device_map_points"] == "0", row
    for name in devices:
        mine = [r for r in rows if r["device"] == name]
        assert len({r["frame"] for r in mine}) == len(mine)       # a frame once
        integrated = int(re.search(rf"^{name}: .*?, (\d+) uploaded", printed, re.M)[1])
        assert sum(int(r["uploaded"]) for r in mine) >= integrated > 0
        assert max(int(r["own_keyframes"]) for r in mine) > 0       # its uploads entered


@ONE_WALK
def test_the_walks_frames_carry_the_devices_search_of_the_map_it_held(
        shared_walk: tuple[str, Path]) -> None:
    """``--frames-csv``'s search columns: of the points in view the device searched at most
    its candidate cap, found only among those searched, and the edge's points a frame
    observed are the map points it reported; the device that joined searched the copies the
    first lent it. Of the edge's points in the image, some are seen from over 60° off where
    the map saw them (the walk turns), and of those searched no more than were in view."""
    _, path = shared_walk
    with path.open(newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    cap = TrackingConfig().max_candidates
    for row in rows:
        n = {key[len("device_"):]: int(value) for key, value in row.items()
             if key.startswith("device_") and key != "device_map_points"}
        for who in ("own", "others", "device"):
            assert 0 <= n[f"searched_{who}"] <= n[f"in_view_{who}"], row
        assert n["searched_own"] + n["searched_others"] + n["searched_device"] <= cap, row
        for who in ("own", "others"):
            assert n[f"found_{who}"] <= n[f"searched_{who}"], row
            assert n[f"searched_afar_{who}"] <= min(n[f"afar_{who}"], n[f"searched_{who}"]), row
        assert n["observed_own"] + n["observed_others"] == int(row["device_map_points"]), row
    joined = [r for r in rows if r["device"] == "ar2"]
    assert max(int(r["device_found_others"]) for r in joined) > 0
    assert sum(int(r["device_afar_own"]) + int(r["device_afar_others"]) for r in rows) > 0
