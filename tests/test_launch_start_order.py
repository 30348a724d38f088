"""``ros2 launch twinslam twinslam_launch.py`` makes a run whatever order its nodes start in: the
player holds its first frame until the device reads the camera. Tried on a busy machine, the
edge and device took ~30 s to start and the player had played every frame to nobody.

The ROS 2 ``launch`` package is not on PyPI, so the launch file is read as Python source: the
player's parameters are the parameter file the launch file passes (``config/twinslam.yaml``,
installed to the package's share) and the launch arguments' defaults it maps onto the player."""

from __future__ import annotations

import ast
import subprocess
import time
from pathlib import Path

import pytest
from twinslam_msgs.msg import FrameSummaries

from msg_schemas import qos
from twinslam.hosts.loopback import LoopbackDomain
from twinslam.node_runtime.session import RosSession

REPO = Path(__file__).resolve().parents[1]
LAUNCH_FILE = REPO / "launch" / "twinslam_launch.py"
PARAMS_FILE = REPO / "config" / "twinslam.yaml"     #: the launch file's params_file default
FRAMES = 120                                       #: four slots of the parameter file's 30
LATE_S = 5.0                                       #: the player alone this long first


def _calls(name: str) -> list[ast.Call]:
    tree = ast.parse(LAUNCH_FILE.read_text(encoding="utf-8"))
    return [n for n in ast.walk(tree) if isinstance(n, ast.Call)
            and isinstance(n.func, ast.Name) and n.func.id == name]


def _keyword(call: ast.Call, name: str) -> ast.expr | None:
    return next((k.value for k in call.keywords if k.arg == name), None)


def launch_parameters(executable: str, **arguments: str) -> list[str]:
    """``-p name:=value`` for each parameter the launch file sets on ``executable`` beside
    its parameter file, each launch argument at its default (or as given in ``arguments``)."""
    defaults = {}
    for call in _calls("DeclareLaunchArgument"):
        default = _keyword(call, "default_value")
        if isinstance(call.args[0], ast.Constant) and isinstance(default, ast.Constant):
            defaults[call.args[0].value] = str(default.value)
    defaults.update(arguments)
    variants = [c for c in _calls("Node") if isinstance(exe := _keyword(c, "executable"),
                                                          ast.Constant) and exe.value == executable]
    # a node the launch file declares twice (with and without an overriding argument) runs as
    # the variant that leaves the parameter file's value: the argument's default is empty
    node = min(variants, key=lambda c: len(ast.unparse(_keyword(c, "parameters") or c)))
    params = _keyword(node, "parameters")
    assert isinstance(params, ast.List)
    out = []
    for item in params.elts:
        if not isinstance(item, ast.Dict):
            continue                                   # the parameter file
        for key, value in zip(item.keys, item.values, strict=True):
            assert isinstance(key, ast.Constant) and isinstance(value, ast.Call), \
                f"{executable}: a parameter this test cannot read: {ast.unparse(value)}"
            if isinstance(value.func, ast.Name) and value.func.id == "ParameterValue":
                value = value.args[0]              # a typed argument: its substitution
                assert isinstance(value, ast.Call), ast.unparse(value)
            argument = value.args[0]
            assert isinstance(argument, ast.Constant)
            out += ["-p", f"{key.value}:={defaults[argument.value]}"]
    return out


def spawn_as_launched(domain: LoopbackDomain, module: str, executable: str,
                      **arguments: str) -> subprocess.Popen[str]:
    """``executable``'s node (``python -m module``) on ``domain`` with the parameter file and
    the parameters the launch file gives it."""
    return domain.spawn(["-m", module, "--ros-args", "--params-file", str(PARAMS_FILE),
                         *launch_parameters(executable, **arguments)])


def test_the_launch_files_player_waits_for_the_device() -> None:
    assert "wait_for_subscribers:=1" in launch_parameters("sequence_player")


@pytest.mark.slow(seconds=25)
def test_nodes_started_late_after_the_player_still_track_every_frame(
        domain: LoopbackDomain, ros: RosSession) -> None:
    summaries: list[FrameSummaries] = []
    ros.node.create_subscription(FrameSummaries, "/device/frame_summaries", summaries.append,
                                 qos.PROTOCOL)

    player = spawn_as_launched(domain, "twinslam.sequence_player.node", "sequence_player",
                               sequence=f"synthetic:{FRAMES}")
    assert domain.wait_for_log(player, "waiting for 1 subscriber(s)", 60), domain.log(player)
    time.sleep(LATE_S)                              # the edge and device start late
    assert player.poll() is None and "published" not in domain.log(player), domain.log(player)
    spawn_as_launched(domain, "edge_mapper.node", "edge_mapper")
    spawn_as_launched(domain, "device_tracker.node", "device_tracker")
    # the player ends once its readers acknowledged every frame; the device may still be
    # tracking the last second of them (a loaded machine), so wait for its last summary too
    assert ros.spin_until(lambda: player.poll() is not None
                          and sum(len(s.frames) for s in summaries) >= FRAMES, 120.0), \
        (sum(len(s.frames) for s in summaries), domain.log(player)[-2000:])
    assert player.returncode == 0 and f"done: {FRAMES} frames published" in domain.log(player)
    frames = [f for s in summaries for f in s.frames]
    assert len(frames) == FRAMES, "the device missed frames the player published"
    assert sum(f.tracked for f in frames) >= 0.9 * FRAMES
