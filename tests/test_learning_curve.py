"""Learning curves: a training run's validated actors are kept as snapshots and
scored on held-out episodes beside the rules; slot 0 is the run's own untrained actor, the kept
one is marked, and each trained actor is paired with its own run's untrained one."""

from __future__ import annotations

import csv
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest

from twinslam.policies.registry import make_policy
from twinslam.policies.world_model import SimConfig
from twinslam.simulator.covisibility_spec import open_covisibility
from twinslam.simulator.evaluation import evaluate

#: torch (and torch_geometric) load inside the tests, and the tests that load them run on one
#: worker: every xdist worker collects every module, and collecting the suite costs 3 s of CPU
#: without torch, 7 s with it
pytestmark = pytest.mark.xdist_group("torch")

COVIS = Path(__file__).resolve().parents[1] / "data" / "7scenes-redkitchen-1000.covis.npz"
HELD_OUT = f"{COVIS}@600:1000"

if TYPE_CHECKING:
    from twinslam.training.trainer import AmmTrainer


def _train(tmp: Path, seed: int) -> tuple[Path, AmmTrainer]:
    from twinslam.training.trainer import AmmTrainer, TrainConfig

    config = TrainConfig(actor="paper", slots=30, warmup_slots=10, validate_every=10,
                         validation_seeds=1, validation_slots=5, batch_size=8, seed=seed)
    trainer = AmmTrainer(config, open_covisibility(f"{COVIS}@0:600"), snapshots=True)
    trainer.train()
    path = tmp / f"run{seed}.snapshots.pt"
    trainer.save_snapshots(path)
    trainer.save(tmp / f"run{seed}.pt")
    return path, trainer


def test_snapshots_are_scored_on_held_out_episodes_beside_the_rules(tmp_path: Path) -> None:
    from twinslam.experiments import learning_curve
    from twinslam.training.trainer import AmmTrainer, TrainConfig, load_snapshots

    files = [_train(tmp_path, seed)[0] for seed in (0, 1)]
    seed, kept, snaps = load_snapshots(files[1])
    assert seed == 1 and [slot for slot, _ in snaps] == [0, 20, 30] and kept in (0, 20, 30)

    points = learning_curve.learning_curve(files, HELD_OUT, tmp_path / "out", episodes=2,
                                           slots=6).points
    with (tmp_path / "out" / "learning_curve.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert {r["policy"] for r in rows} == {"LFF", "PU", "ADAPT", "RANDOM", "AMM snapshot"}
    for run in ("0", "1"):
        mine = [r for r in rows if r["training_seed"] == run]
        assert [int(r["training_slot"]) for r in mine] == [0, 20, 30]
        assert sum(r["kept"] == "True" for r in mine) == 1     # exactly the kept checkpoint
    # the rules play the episodes a plain evaluation of the held-out seeds plays
    channel = points[0].task.setup.channel
    lff = next(p for p in points if p.task.policy == "lff")
    direct = evaluate(["lff"], open_covisibility(HELD_OUT), channel, SimConfig(slots=6),
                      [0, 1], make_policy=make_policy)[0]
    assert np.allclose(lff.per_episode, [r.mean_uncertainty for r in direct.runs])
    # slot 0 is the run's untrained actor: it plays exactly what that actor plays
    AmmTrainer(TrainConfig(actor="paper", seed=1, validate_every=0),
               open_covisibility(f"{COVIS}@0:600")).save(tmp_path / "untrained1.pt")
    again = evaluate([f"mbrl:{tmp_path / 'untrained1.pt'}"], open_covisibility(HELD_OUT),
                     channel, SimConfig(slots=6), [0, 1], make_policy=make_policy)[0]
    untrained = next(p for p in points if p.task.slot == 0 and "run1" in p.task.snapshots)
    assert np.allclose(untrained.per_episode, [r.mean_uncertainty for r in again.runs])
    with (tmp_path / "out" / "learning_curve_paired.csv").open() as fh:
        paired = {r["comparison"]: r for r in csv.DictReader(fh)}
    best = min((p for p in points if p.task.policy in ("lff", "pu", "adapt")),
               key=lambda p: p.per_episode.mean()).task.policy.upper()
    assert set(paired) == {f"{which} actor - {other}" for which in ("kept", "last")
                           for other in ("untrained actor (same run)", f"best rule ({best})")}
    assert all(int(r["runs"]) == 2 for r in paired.values())
    with (tmp_path / "out" / "learning_curve_controls.csv").open() as fh:
        controls = {r["policy"]: r for r in csv.DictReader(fh)}
    assert set(controls) == {"LFF", "PU", "ADAPT", "RANDOM", "Untrained AMM (slot 0)",
                             "Trained AMM, kept (validation)", "Trained AMM, last"}
    assert controls["Untrained AMM (slot 0)"]["training_runs"] == "2"
    assert float(controls["Untrained AMM (slot 0)"]["mean_uncertainty"]) == pytest.approx(
        np.mean([p.per_episode.mean() for p in points if p.task.slot == 0]))
    assert controls[best]["paired_vs_best_rule"] == ""          # the baseline itself
    assert (tmp_path / "out" / "learning_curve.png").stat().st_size > 10_000


def test_a_training_stopped_half_way_keeps_its_checkpoint_and_snapshots_so_far(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Each validation saves what there is (a 30 000-slot run killed at slot 20 000 keeps
    its curve to there): here the run dies right after its second validation."""
    from twinslam.experiments.training import TrainTask, snapshots_path, train_one
    from twinslam.training.trainer import AmmTrainer, TrainConfig, load_snapshots

    original = AmmTrainer._keep_if_best

    def dies_after_two(self: AmmTrainer, played: int) -> None:
        original(self, played)
        if len(self.validations) == 2:
            raise KeyboardInterrupt
    monkeypatch.setattr(AmmTrainer, "_keep_if_best", dies_after_two)
    config = TrainConfig(actor="paper", slots=30, warmup_slots=10, validate_every=10,
                         validation_seeds=1, validation_slots=5, batch_size=8)
    task = TrainTask(config, f"{COVIS}@0:600", tmp_path / "run.pt", snapshots=True)
    with pytest.raises(KeyboardInterrupt):
        train_one(task)
    _, kept, snaps = load_snapshots(snapshots_path(tmp_path / "run.pt"))
    assert [slot for slot, _ in snaps] == [0, 20] and kept in (0, 20)
    assert (tmp_path / "run.pt").is_file()


def test_thinning_keeps_the_first_the_last_and_the_kept_snapshot() -> None:
    from twinslam.experiments import learning_curve

    slots = [0, 500, 1000, 1500, 2000, 2500, 2700]
    assert learning_curve.thinned(slots, 1500, 1000) == [0, 1000, 1500, 2000, 2700]
    assert learning_curve.thinned(slots, 1000, 0) == slots


def test_a_checkpoint_is_not_a_snapshots_file(tmp_path: Path) -> None:
    from twinslam.experiments import learning_curve

    _, trainer = _train(tmp_path, 0)
    with pytest.raises(ValueError, match="not a training's snapshots"):
        learning_curve.setup_of([tmp_path / "run0.pt"], HELD_OUT, 2, 6)
    with pytest.raises(ValueError, match="no such snapshots file"):
        learning_curve.setup_of([tmp_path / "missing.snapshots.pt"], HELD_OUT, 2, 6)
    assert trainer.snapshots
