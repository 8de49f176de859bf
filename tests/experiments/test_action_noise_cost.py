"""experiments/action_noise_cost.py: noise lands on one component only, the same draws in every condition."""

from __future__ import annotations

import pytest
import torch

from experiments.action_noise_cost import GROUPS, main, noisy


def test_noise_only_on_the_component_and_the_same_draws_for_every_component():
    policy = lambda obs: torch.full((3, 28), 0.25)
    ref = torch.randn((3, 28), generator=torch.Generator().manual_seed(7))
    for name, cols in GROUPS.items():
        out = noisy(policy, cols, 0.5, torch.Generator().manual_seed(7))(None)
        mask = torch.zeros(28, dtype=torch.bool)
        mask[cols] = True
        assert torch.equal(out[:, mask], 0.25 + 0.5 * ref[:, mask]), name
        assert torch.equal(out[:, ~mask], torch.full((3, int((~mask).sum())), 0.25)), name
    assert [len(range(28)[c]) for c in GROUPS.values()] == [4, 4, 8, 12, 28]


@pytest.mark.parametrize("argv, message", [
    (["--sigmas", "0"], "every noise std must be > 0"),
    (["--episodes", "3"], "give an even number"),
    (["--policy", "/nonexistent.pt2"], "not found"),
    (["--groups", "q"], "invalid choice"),
    (["--no-such-flag"], "unrecognized arguments: --no-such-flag"),
])
def test_bad_input_is_one_line(argv, message, capsys):
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    assert message in capsys.readouterr().err


def test_help_names_the_components(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--help"])
    assert e.value.code == 0
    assert "--sigmas" in capsys.readouterr().out
