"""Folders the tests read from, in one place (importable from every test folder: tests/conftest.py puts tests/ on
``sys.path``)."""

from pathlib import Path

TESTS = Path(__file__).resolve().parent
REPO = TESTS.parent
# the bundled example of the toy-arm plugin: URDF, trajectory, camera, first frame
TOYARM_ASSETS = REPO / "examples" / "oscar-toyarm" / "oscar_toyarm" / "assets"
# reference files kept beside the repository (vendor URDFs the plugins are checked against); absent on CI
SHARED = REPO.parent / "shared"
