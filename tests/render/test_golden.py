"""The golden-image helper and its pytest plugin, as a plugin author uses them."""

import numpy as np
import pytest

from oscar_core.testing import assert_matches_golden, compare_images

pytest_plugins = ["pytester"]


def test_compare_images_hand_worked():
    a = np.zeros((2, 2, 3), np.uint8)
    b = a.copy()
    b[0, 0, 0] = 12  # one of 12 values differs by 12: RMS = sqrt(144 / 12) = sqrt(12)
    assert compare_images(a, b) == pytest.approx(np.sqrt(12.0))
    assert compare_images(a, a) == 0.0
    with pytest.raises(ValueError, match="sizes differ"):
        compare_images(a, np.zeros((2, 3, 3), np.uint8))


def test_assert_matches_golden_writes_three_images_on_failure(tmp_path):
    img = np.full((8, 8, 3), 100, np.uint8)
    golden = tmp_path / "g.png"
    assert_matches_golden(img, golden, tol=0, results_dir=tmp_path / "res", regenerate=True)
    assert_matches_golden(img, golden, tol=0, results_dir=tmp_path / "res")  # exact match passes at tol 0
    changed = img.copy()
    changed[0, 0] = 110
    assert_matches_golden(changed, golden, tol=2.0, results_dir=tmp_path / "res")  # RMS sqrt(300/192) < 2
    with pytest.raises(AssertionError, match=r"RMS 1.250 > tolerance 0") as info:
        assert_matches_golden(changed, golden, tol=0, results_dir=tmp_path / "res")
    for kind in ("actual", "expected", "diff"):
        assert (tmp_path / "res" / f"g-{kind}.png").is_file() and f"g-{kind}.png" in str(info.value)
    with pytest.raises(AssertionError, match="size"):
        assert_matches_golden(np.zeros((4, 8, 3), np.uint8), golden, tol=100, results_dir=tmp_path / "res")


PLUGIN_TEST = """
import numpy as np

def test_image(golden):
    img = np.zeros((16, 16, 3), np.uint8)
    img[4:12, 4:12] = {value}
    golden.check(img, "square.png", tol=0.5)
"""


def test_plugin_fixture_regenerates_only_on_request(pytester):
    # the plugin comes in through its pytest11 entry point, as it does for plugin authors
    pytester.makepyfile(test_sq=PLUGIN_TEST.format(value=200))
    missing = pytester.runpytest()
    missing.assert_outcomes(failed=1)
    missing.stdout.fnmatch_lines(["*does not exist*--oscar-regen-golden*"])
    created = pytester.runpytest("--oscar-regen-golden")
    created.assert_outcomes(passed=1)
    assert (pytester.path / "golden" / "square.png").is_file()
    pytester.runpytest().assert_outcomes(passed=1)
    pytester.makepyfile(test_sq=PLUGIN_TEST.format(value=180))
    changed = pytester.runpytest("--oscar-golden-results", "out")
    changed.assert_outcomes(failed=1)
    assert sorted(p.name for p in (pytester.path / "out").iterdir()) == [
        "square-actual.png",
        "square-diff.png",
        "square-expected.png",
    ]


def test_default_results_folder_is_under_the_rootdir(pytester):
    pytester.makepyfile(test_sq=PLUGIN_TEST.format(value=90))
    pytester.runpytest("--oscar-regen-golden").assert_outcomes(passed=1)
    pytester.makepyfile(test_sq=PLUGIN_TEST.format(value=95))
    result = pytester.runpytest()
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(["*RMS * > tolerance 0.5*", "*golden-results*square-actual.png*"])
    assert (pytester.path / "golden-results" / "square-diff.png").is_file()


@pytest.mark.parametrize("how", ["-p", "conftest"])
def test_plugin_loaded_twice_is_harmless(pytester, how):
    """Entry point plus ``-p module`` (or ``pytest_plugins``) must not be a duplicate registration."""
    pytester.makepyfile(
        test_fx="""
def test_fixture(golden, request):
    assert golden.folder == request.path.parent / "golden" and golden.regenerate
"""
    )
    if how == "conftest":
        pytester.makeconftest('pytest_plugins = ["oscar_core.testing.pytest_plugin"]')
        args = []
    else:
        args = ["-p", "oscar_core.testing.pytest_plugin"]
    pytester.runpytest(*args, "--oscar-regen-golden").assert_outcomes(passed=1)


def test_plugin_import_is_light():
    import subprocess
    import sys

    code = (
        "import sys, oscar_core.testing.pytest_plugin; "
        "print(sorted(m for m in ('numpy', 'cv2', 'torch', 'av') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
