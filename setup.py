"""Packaging beyond pyproject.toml: the top-level configs/ folder ships inside the package as torchrefl/configs/
(torchrefl.config_bundle finds it there in a wheel, and beside the package in a checkout)."""

from setuptools import find_namespace_packages, setup

setup(
    # namespace packages too (torchrefl/transport/levels has no __init__.py), as pyproject's packages.find found them
    packages=[*find_namespace_packages(include=["torchrefl*"], exclude=["*__pycache__"]), "torchrefl.configs"],
    package_dir={"torchrefl.configs": "configs"},
)
