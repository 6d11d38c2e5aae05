"""Packaging beyond pyproject.toml: the top-level configs/ folder ships inside the package as torchrefl/configs/
(torchrefl.config_bundle finds it there in a wheel, and beside the package in a checkout)."""

from setuptools import find_packages, setup

setup(
    packages=[*find_packages(include=["torchrefl*"]), "torchrefl.configs"],
    package_dir={"torchrefl.configs": "configs"},
)
