"""The tracking benchmarks' seed mapping: which runs are one vmapped program."""

import pytest

from benchmarks import ppo_tracking


@pytest.mark.parametrize(
    ("seed_map", "policy", "backend", "vmapped"),
    [
        ("auto", "mlp", "cpu", True),
        ("auto", "lstm", "cpu", False),  # one program per seed on XLA:CPU
        ("auto", "lstm", "gpu", True),
        ("loop", "mlp", "gpu", False),
        ("vmap", "lstm", "cpu", True),
    ],
)
def test_seeds_vmapped(seed_map, policy, backend, vmapped):
    assert ppo_tracking.seeds_vmapped(seed_map, policy, backend) is vmapped


def test_seed_map_choices_are_checked(capsys):
    with pytest.raises(SystemExit) as exc:
        ppo_tracking.main(["--seed-map", "pmap"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.replace("'", "")
    assert "--seed-map: invalid choice: pmap (choose from auto, vmap, loop)" in err
