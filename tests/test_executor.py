"""Sweeps on either executor: the same seeds give the same numbers in this
process, in local worker processes and on a local Ray of 2 CPUs; a task that fails is reported
with what it was and its traceback while the others finish; bad executor options are refused
by name."""

from __future__ import annotations

import csv
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from twinslam.covisibility.dataset import CovisibilityDataset
from twinslam.experiments.amm import Setting, sweep
from twinslam.simulator.covisibility_spec import open_covisibility
from twinslam.sweeps import (
    Executor,
    LocalExecutor,
    RayExecutor,
    make_executor,
    run_tasks,
)

REPO = Path(__file__).resolve().parents[1]
COVIS = REPO / "data" / "7scenes-redkitchen-1000.covis.npz"
#: two good specs around one that names no file: the middle task must fail in its worker
SPECS = ["geometric:40:1", str(REPO / "no-such.covis.npz"), "geometric:30:2"]


#: the tests that run tasks on this process's Ray: one worker starts it once for all of them
ON_ONE_RAY = pytest.mark.xdist_group("local-ray")


@pytest.fixture(scope="module")
def local_ray() -> Iterator[None]:
    """A local Ray of 2 CPUs for this module's in-process Ray tests (started once: a start
    costs seconds of CPU); an executor made while it runs joins it and leaves it running."""
    with RayExecutor(cpus=2):
        yield


def _chosen(executor: str, local_ray: None) -> Executor:
    return RayExecutor(cpus=2) if executor == "ray" else \
        LocalExecutor(int(executor.rpartition("-")[2]))


def _frames(data: CovisibilityDataset) -> str:
    return f"{data.n_frames} frames"


def _twin_predict(tmp_path: Path, name: str, *executor: str) -> list[dict[str, str]]:
    out = tmp_path / name
    done = subprocess.run(
        [sys.executable, "-m", "twinslam.cli.main", "experiment", "twin-predict", *executor,
         "--runs", "2", "--source", "stationary", "--predictor", "markov", "--slots", "200",
         "--out", str(out)], capture_output=True, text=True, timeout=240, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    shown = done.stdout + done.stderr
    assert "[2/2]" in shown and "ETA" in shown                  # progress as runs land
    with (out / "twin_predict_runs.csv").open() as fh:
        return list(csv.DictReader(fh))


@pytest.mark.slow(seconds=60)
@ON_ONE_RAY
def test_twin_predict_gives_the_same_numbers_on_ray_as_locally(tmp_path: Path,
                                                                local_ray: None) -> None:
    """The sweep command on the local executor and on a running Ray of 2 CPUs that it joins
    by address (as a cluster's `ray start --head` prints it): the same runs, to the digit."""
    import ray

    address = ray.get_runtime_context().gcs_address
    local = _twin_predict(tmp_path, "local", "--executor", "local")
    on_ray = _twin_predict(tmp_path, "ray", "--executor", "ray", "--ray-address", address)
    assert len(local) == 2 and {r["seed"] for r in local} == {"0", "1"}
    assert on_ray == local


@ON_ONE_RAY
@pytest.mark.parametrize("executor", ["local-1", "local-2", "ray"])
def test_a_failing_task_is_reported_with_its_traceback_and_the_others_finish(
        executor: str, tmp_path: Path, local_ray: None) -> None:
    lines: list[str] = []
    failures = tmp_path / "failures.txt"
    chosen = _chosen(executor, local_ray)
    with chosen:
        done = run_tasks(open_covisibility, SPECS, chosen, lambda spec: f"covis {spec}",
                         _frames, lines.append, failures)
    assert sorted(done.results) == [0, 2]                       # the others finished
    assert [d.n_frames for d in done.in_order()] == [40, 30]
    [failure] = done.failures
    assert failure.index == 1 and failure.task == f"covis {SPECS[1]}"
    assert "Traceback" in failure.error and "no-such.covis.npz" in failure.last_line
    assert any("FAILED covis" in line and "the other tasks go on" in line for line in lines)
    assert sum("frames (" in line and "ETA" in line for line in lines) == 2
    assert "no-such.covis.npz" in failures.read_text()


@pytest.mark.slow(seconds=20)
def test_figure_points_are_the_same_in_one_process_and_in_two_workers(tmp_path: Path) -> None:
    """A figure's episodes spread over worker processes: every policy's score per seed is the
    one the single process computed."""
    results = []
    for jobs in (1, 2):
        with LocalExecutor(jobs) as executor:
            results.append(sweep(f"fig{jobs}", [0.3, 0.7], lambda r: f"markov:N=2,ratio={r}",
                                 lambda _r: Setting(runs=3, slots=6), str(COVIS), {},
                                 tmp_path, "ratio", reference=False, plot=False,
                                 executor=executor))
    one, two = results
    for x in (0.3, 0.7):
        for label in ("LFF", "PU", "ADAPT"):
            assert two[x][label].per_seed == one[x][label].per_seed
    assert ((tmp_path / "fig1_runs.csv").read_text().splitlines()[1:]
            == (tmp_path / "fig2_runs.csv").read_text().splitlines()[1:])


def test_bad_executor_options_are_refused_by_name() -> None:
    with pytest.raises(ValueError, match="--ray-address needs --executor ray"):
        make_executor("local", 1, "127.0.0.1:6379")
    with pytest.raises(ValueError, match="--jobs must be >= 1"):
        make_executor("local", 0)
    with pytest.raises(ValueError, match="unknown executor 'dask'"):
        make_executor("dask")


def test_training_runs_in_workers_get_one_torch_thread_each() -> None:
    """Two torch threads a run in two workers oversubscribed a 2-core machine and ran its
    trainings ~5× slower: runs that share the cores get one thread each unless told."""
    from argparse import Namespace

    from twinslam.cli.commands.train import threads_per_run

    def threads(**kw: object) -> int:
        return threads_per_run(Namespace(**{"threads": None, "jobs": None,
                                            "executor": "local", **kw}))
    assert threads() == 2                           # one run, in this process
    assert threads(jobs=2) == 1 and threads(executor="ray") == 1
    assert threads(jobs=2, threads=3) == 3          # asked for
    with pytest.raises(ValueError, match="--threads must be >= 1"):
        threads(threads=0)


WORKER_SCRIPT = """
import torch   # loaded before the pool starts: a spawned worker re-imports this module first
from twinslam.sweeps import LocalExecutor

def threads(_: int) -> int:
    return torch.get_num_threads()

if __name__ == "__main__":
    with LocalExecutor(2) as pool:
        print(sorted(outcome.value for _, outcome in pool.submit_all(threads, [0, 1])))
"""


def test_a_worker_runs_torch_on_one_thread_even_when_its_main_module_loaded_it(
        tmp_path: Path) -> None:
    """`twinslam sim --jobs N` with torch policies: the workers' torch was loaded by the
    re-imported main module before OMP_NUM_THREADS=1 was set, so each ran a thread per core
    (16 workers x 16 threads on a 16-core machine). The worker's set-up now sets it directly."""
    script = tmp_path / "pool.py"
    script.write_text(WORKER_SCRIPT)
    unset = {k: v for k, v in os.environ.items() if k != "OMP_NUM_THREADS"}   # (conftest's)
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                          timeout=120, cwd=REPO, env=unset)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[1, 1]"


def test_the_commands_that_run_no_torch_do_not_load_it() -> None:
    """torch costs seconds to import and each spawned worker re-imports the command line:
    `twinslam sim` and the node commands must not pay for it."""
    probe = "import sys, twinslam.cli.main; print('torch' in sys.modules)"
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          timeout=120, cwd=REPO)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "False"


def test_the_cli_says_when_ray_cannot_be_joined(tmp_path: Path) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "twinslam.cli.main", "experiment", "twin-predict",
         "--executor", "ray", "--ray-address", "127.0.0.1:1", "--runs", "1",
         "--source", "stationary", "--predictor", "markov", "--slots", "50",
         "--out", str(tmp_path / "out")], capture_output=True, text=True, timeout=180)
    assert done.returncode == 2
    assert "could not start or join Ray at 127.0.0.1:1" in done.stderr
    assert not (tmp_path / "out").exists()


@ON_ONE_RAY
@pytest.mark.parametrize("executor", ["local-2", "ray"])
def test_a_worker_that_dies_is_a_failed_task_not_a_dead_sweep(executor: str,
                                                               local_ray: None) -> None:
    """A task that takes its worker process down (os._exit: a segfault, the OOM killer) is
    reported as that task's failure; the command goes on to write what it has."""
    chosen = _chosen(executor, local_ray)
    with chosen:
        done = run_tasks(os._exit, [3], chosen, lambda code: f"exit {code}", str)
    assert not done.results
    [failure] = done.failures
    assert failure.task == "exit 3" and failure.error
