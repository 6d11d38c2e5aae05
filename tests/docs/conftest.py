"""The doc blocks that were not run, each with its marker's reason, listed at the end of every run that had some."""

DOC_TEST = "test_doc_block_runs_as_written"


def pytest_terminal_summary(terminalreporter):
    skipped = [r for r in terminalreporter.stats.get("skipped", []) if DOC_TEST in r.nodeid]
    if not skipped:
        return
    terminalreporter.section("doc blocks not run (their markers in the markdown)")
    for report in skipped:
        reason = report.longrepr[2] if isinstance(report.longrepr, tuple) else str(report.longrepr)
        terminalreporter.write_line(reason.removeprefix("Skipped: "))
