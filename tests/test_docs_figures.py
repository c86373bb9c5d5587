"""make docs-figures: a page drawn by headless Chromium and cut below its end."""

import shutil

import pytest

from runners.docs_figures import BROWSERS, FIGURES, ROOT, screenshot


@pytest.mark.skipif(not any(shutil.which(b) for b in BROWSERS), reason="needs Chromium")
def test_screenshot_is_the_page_cut_below_its_end(tmp_path):
    """A page of one 300 px red block on white, 600 px wide: the png is 600 px wide, 300 + 24 px
    high, red at the top left and white below the block."""
    import numpy as np
    from PIL import Image

    html = tmp_path / "page.html"
    html.write_text('<html><body style="margin:0;background:#fff">'
                    '<div style="width:200px;height:300px;background:#f00"></div></body></html>')
    png = screenshot(html, tmp_path / "page.png", width=600)
    a = np.asarray(Image.open(png).convert("RGB"))
    assert a.shape == (324, 600, 3)
    assert tuple(a[10, 10]) == (255, 0, 0) and tuple(a[310, 10]) == (255, 255, 255)
    assert tuple(a[10, 300]) == (255, 255, 255)


def test_every_figure_is_a_file_of_the_repository_made_by_a_command_that_names_a_scenario():
    for png, cli in FIGURES.values():
        assert (ROOT / png).is_file() and png.endswith(".png")
        assert cli[0] in ("run", "baseline") and (ROOT / cli[1]).exists()
