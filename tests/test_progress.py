"""Progress bars: silent in scripts and tests, shown at a terminal or when forced, same results."""

import io
import sys

import numpy as np
import pytest

from drapejax import refine
from drapejax.diagnose import trials
from drapejax.progress import ENV_VAR, bar

from helpers import QuadraticProblem


class _Terminal(io.StringIO):
    """A stderr that says it is a terminal."""

    def isatty(self):
        return True


def test_bar_is_silent_by_default_off_a_terminal(capfd, monkeypatch):
    monkeypatch.delenv(ENV_VAR, raising=False)
    assert list(bar(range(3), desc="quiet loop")) == [0, 1, 2]
    with bar(total=2, desc="quiet stages") as b:
        b.update()
        b.set_postfix(loss="1.0")
    out, err = capfd.readouterr()
    assert out == "" and err == ""


def test_env_var_forces_the_bar_on(capfd, monkeypatch):
    monkeypatch.setenv(ENV_VAR, "1")
    assert list(bar(range(3), desc="forced loop")) == [0, 1, 2]
    out, err = capfd.readouterr()
    assert out == ""
    assert "forced loop" in err and "3/3" in err


@pytest.mark.parametrize("flag, shown", [(None, True), ("0", False), ("1", True)])
def test_a_terminal_shows_the_bar_unless_forced_off(monkeypatch, flag, shown):
    if flag is None:
        monkeypatch.delenv(ENV_VAR, raising=False)
    else:
        monkeypatch.setenv(ENV_VAR, flag)
    term = _Terminal()
    monkeypatch.setattr(sys, "stderr", term)
    list(bar(range(2), desc="terminal loop"))
    assert ("terminal loop" in term.getvalue()) == shown


def test_the_fit_shows_its_iterations_and_misfit_without_changing_the_result(capfd, monkeypatch):
    monkeypatch.delenv(ENV_VAR, raising=False)
    quiet = refine.run_lm(QuadraticProblem(), np.zeros(4), max_steps=20)
    assert capfd.readouterr().err == ""
    monkeypatch.setenv(ENV_VAR, "1")
    shown = refine.run_lm(QuadraticProblem(), np.zeros(4), max_steps=20)
    err = capfd.readouterr().err
    assert "LM fit" in err and "loss=" in err and f"status={shown.status}" in err
    np.testing.assert_array_equal(shown.theta, quiet.theta)
    assert (shown.loss, shown.steps, shown.status, shown.history) == (quiet.loss, quiet.steps, quiet.status,
                                                                      quiet.history)


def test_the_diagnosis_fresh_drops_show_a_bar(capfd, monkeypatch):
    class Drops:
        n_rows = 1

        def drop(self, theta, seed):
            return np.full((2, 3), float(seed))

        def evaluate(self, theta, x, jacobian):
            return np.array([x[0, 0] - 1.0]), None

    monkeypatch.setenv(ENV_VAR, "1")
    drops = trials._drops(Drops(), [(np.zeros(3), s) for s in range(4)])
    assert [d["seed"] for d in drops] == [0, 1, 2, 3]
    err = capfd.readouterr().err
    assert "fresh drops" in err and "4/4" in err
