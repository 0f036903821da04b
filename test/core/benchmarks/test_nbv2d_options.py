"""The 2D benchmark's --run-option: switches are parsed as switches, bad items are named."""

from __future__ import annotations

import pytest

from benchmarks import nbv2d as bench


@pytest.mark.parametrize(("text", "expected"), [("false", False), ("False", False), ("0", False), ("TRUE", True)])
def test_a_switch_reads_true_and_false_in_any_case(text, expected):
    assert bench.run_options([f"s2_skip_predicted_d2={text}"]) == {"s2_skip_predicted_d2": expected}


def test_numbers_and_texts():
    got = bench.run_options(["circ_max_laps=2", "s2_orbit_budget=none", "s2_orbit_budget_factor=1.5"])
    assert got == {"circ_max_laps": 2, "s2_orbit_budget": "none", "s2_orbit_budget_factor": 1.5}


@pytest.mark.parametrize(
    ("item", "named"),
    [
        ("s2_skip_predicted_d2=maybe", "is a switch"),
        ("no_such_option=1", "expected NAME=VALUE"),
        ("circ_max_laps", "expected NAME=VALUE"),
    ],
)
def test_bad_items_are_named(item, named):
    with pytest.raises(ValueError, match=named) as err:
        bench.run_options([item])
    assert item in str(err.value)


def test_the_command_exits_2_on_a_bad_switch(capsys, tmp_path):
    with pytest.raises(SystemExit) as exc:
        bench.main(["--run-option", "s2_skip_predicted_d2=maybe", "--json", str(tmp_path / "b.json")])
    assert exc.value.code == 2
    assert "is a switch" in capsys.readouterr().err
    assert not (tmp_path / "b.json").exists()
