import numpy as np

from gpja.register.openings import SOCKET_DARK_FRACTION, dark_openings, inside_silhouette, opened


def test_an_opening_keeps_wide_dark_regions_and_drops_thin_lines():
    """Analytic: a 9 x 9 square survives an opening of width 5 but for its corners (the disc's rounding); a line 2 px
    thick (closed lips' contact line) vanishes; nothing is added; an empty region stays empty."""
    region = np.zeros((30, 30), dtype=bool)
    region[5:14, 5:14] = True
    region[20:22, 2:28] = True
    out = opened(region, 5)
    np.testing.assert_array_equal(out[6:13, 6:13], True)
    assert not (out & ~region).any() and not out[18:].any() and out.sum() >= 81 - 8
    assert not opened(np.zeros((30, 30), dtype=bool), 5).any()


def test_the_silhouette_keeps_enclosed_holes_and_leaves_the_background_out():
    """Analytic: a covered ring encloses a hole (inside) and the rest of the image reaches the border (outside); with
    nothing covered nothing is inside; with everything covered everything is."""
    yy, xx = np.mgrid[:40, :40]
    r = np.hypot(yy - 20, xx - 20)
    covered = (r < 15) & (r > 5)
    inside = inside_silhouette(covered)
    np.testing.assert_array_equal(inside, r < 15)  # the ring and the hole it encloses
    assert not inside_silhouette(np.zeros((8, 8), dtype=bool)).any()
    assert inside_silhouette(np.ones((8, 8), dtype=bool)).all()


def test_dark_openings_finds_an_open_mouth_and_not_a_contact_line_or_the_background():
    """A bright covered face with a dark 10 x 6 px mouth hole (not covered, as a scan leaves it), a 2 px dark contact
    line, and a dark background beside it: only the hole is an opening. Brightening the hole removes it."""
    grey = np.full((60, 60), 30, dtype=np.uint8)  # background, dark
    coverage = np.zeros((60, 60))
    coverage[10:50, 10:50] = 1.0
    grey[10:50, 10:50] = 160
    coverage[20:26, 25:35] = 0.0
    grey[20:26, 25:35] = int(160 * SOCKET_DARK_FRACTION) - 40
    grey[38:40, 20:40] = 40  # a closed mouth's contact line
    found = dark_openings(grey, coverage)
    hole = np.zeros_like(found)
    hole[20:26, 25:35] = True
    assert not (found & ~hole).any()
    assert found.sum() >= 0.75 * hole.sum()
    grey[20:26, 25:35] = 150
    assert not dark_openings(grey, coverage).any()


def test_a_dark_background_is_an_opening_only_when_asked():
    """``within_head=False`` (the flow stage's switch as measured) counts a dark background as well."""
    grey = np.full((40, 40), 30, dtype=np.uint8)
    coverage = np.zeros((40, 40))
    coverage[10:30, 10:30] = 1.0
    grey[10:30, 10:30] = 160
    assert not dark_openings(grey, coverage).any()
    outside = dark_openings(grey, coverage, within_head=False)
    np.testing.assert_array_equal(outside, coverage == 0)
