"""scripts/fit_error_budget.py on the tiny fold (its tiny mode's run): the Pd budget table and the held-out line."""

from conftest import load_script

budget = load_script("fit_error_budget")


def test_the_budget_of_the_tiny_fold(tiny_fold_run, capsys):
    run = tiny_fold_run
    assert budget.main(["--tiny", str(budget.FOLD), str(run / "capture"), str(run)]) == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith("| ") and "---" not in line]
    assert rows[0].startswith("| Pd from | pd_rmse |") and len(rows) == 5
    assert "held-out mean |diff| (8-bit): run " in out
