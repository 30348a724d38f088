"""The layers of docs/architecture.md §5 as a user meets them: an edge that runs a rule-based policy
never loads torch (seconds of start-up and ~1 GB of address space it does not need).

`make test` checks the static contract (``lint-imports``, pyproject.toml); these tests check
what a process actually imports, where a lazy import could still pull torch in.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

PROBE = """
import json, sys
{imports}
print(json.dumps(sorted(m for m in sys.modules if m.split('.')[0] in ('torch', 'torch_geometric'))))
"""


def _torch_modules_after(imports: str) -> list[str]:
    out = subprocess.run([sys.executable, "-c", PROBE.format(imports=imports)], cwd=REPO,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_an_edge_with_a_rule_policy_imports_no_torch() -> None:
    loaded = _torch_modules_after(
        "import edge_mapper.node\n"
        "from twinslam.policies.registry import make_policy\n"
        "for name in ('lff', 'pu', 'adapt', 'random'):\n"
        "    make_policy(name)\n")
    assert loaded == []


def test_the_probe_sees_torch_where_it_is_loaded() -> None:
    """The twin node needs torch: the probe that found none above finds it here."""
    assert "torch" in _torch_modules_after("import udt_node.node\n")


def test_a_regime_or_counting_rate_model_never_loads_torch() -> None:
    """The rate-model registry builds the learned models on demand: a caller on the regime
    twin or the counts (a twin node on the default model's library, the prediction
    experiment's filters) does not pay for torch."""
    loaded = _torch_modules_after(
        "from twinslam.twin.registry import make_rate_model\n"
        "for name in ('regime', 'markov', 'markov-window', 'persistence', 'uniform'):\n"
        "    make_rate_model(name).observe(1)\n")
    assert loaded == []
