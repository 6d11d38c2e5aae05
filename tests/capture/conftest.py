"""Fixtures of the capture tests."""

import json

import pytest


@pytest.fixture
def write_json(tmp_path):
    """write_json(name, doc) -> the path of tmp_path / name holding doc as JSON (a str is written as it is)."""

    def write(name: str, doc):
        path = tmp_path / name
        path.write_text(doc if isinstance(doc, str) else json.dumps(doc))
        return path

    return write
