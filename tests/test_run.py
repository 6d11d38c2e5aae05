"""torchrefl.fit / torchrefl.run.run as a library call: what it prints."""

from report.test_run_folder import tiny_capture_args

from torchrefl.run import fit


def test_fit_quiet_prints_nothing_and_loud_only_logs_on_stderr(tmp_path, capsys):
    """Issue 33: fit(..., quiet=True) still drew progress bars on stderr unless output.progress was false."""
    config = tiny_capture_args(tmp_path)[0]
    run = fit(config, [f"output.dir={tmp_path / 'quiet'}"], quiet=True)
    streams = capsys.readouterr()
    assert (streams.out, streams.err) == ("", "")
    assert run.mask.any() and run.config["output"]["progress"] is True  # the recorded config is the one given
    fit(config, [f"output.dir={tmp_path / 'loud'}"], quiet=False)
    streams = capsys.readouterr()
    assert streams.out == ""
    assert "[capture] done" in streams.err and "fit (none)" in streams.err and "torchrefl summary" not in streams.err
