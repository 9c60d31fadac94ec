"""gpja.metrics.regions: facial regions of rest-space points from the 68 landmarks."""
from __future__ import annotations

import numpy as np
import pytest

from gpja.data.synthetic.head import HeadParams
from gpja.data.synthetic.landmarks import rest_landmark_guesses
from gpja.errors import InputError
from gpja.metrics.regions import (
    FOREHEAD_MM,
    LANDMARK_GROUPS,
    RADII_MM,
    REGIONS,
    UNLABELLED,
    face_polygon,
    label_regions,
    region_statistics,
)

#: A landmark set in the synthetic head's construction (before snapping): the frame every subject shares.
L = rest_landmark_guesses(HeadParams())


def names(labels):
    return [REGIONS[k] if k >= 0 else "unlabelled" for k in labels]


def test_each_landmark_lies_in_its_own_feature_region():
    for group, indices in LANDMARK_GROUPS.items():
        assert set(names(label_regions(L[list(indices)], L))) == {group}, group


def test_points_around_the_face_fall_where_a_person_would_put_them():
    mouth_y, chin = L[51, 1] - 4.0, L[8]
    cheek = 0.5 * (L[3] + L[31])  # between the jaw line and the nose's side, on the face
    points = {
        "mouth": (0.0, mouth_y, L[51, 2] - 12.0),  # deep inside the mouth, behind the lips (outer-lip polygon)
        "eyes": (*L[[37, 38, 40, 41], :2].mean(axis=0), L[36:42, 2].min() - 8.0),  # the eyeball, behind the lids
        "face": cheek,
        "outer": (0.0, chin[1] - 30.0, chin[2] - 10.0),  # the neck below the chin
    }
    forehead = (0.0, L[17:27, 1].max() + FOREHEAD_MM - 5.0, L[27, 2])
    above = (0.0, L[17:27, 1].max() + FOREHEAD_MM + 15.0, L[27, 2] - 10.0)
    ear, back = (L[0, 0] - 8.0, L[0, 1], L[0, 2] - 10.0), (0.0, 0.0, -90.0)
    labels = names(label_regions(np.array([*points.values(), forehead, above, ear, back]), L))
    assert labels == [*points, "face", "outer", "outer", "outer"]


def test_radii_bound_the_feature_regions():
    brow, r = L[19], RADII_MM["brows"]
    inside, outside = brow + [0, 0.9 * r, 0], brow + [0, 1.1 * r, 0]  # up the forehead
    assert names(label_regions(np.array([inside, outside]), L)) == ["brows", "face"]


def test_nan_rows_are_unlabelled_and_bad_landmarks_raise():
    labels = label_regions(np.array([[np.nan, 0, 0], L[30]]), L)
    assert labels.dtype == np.int8 and labels[0] == UNLABELLED and REGIONS[labels[1]] == "nose"
    assert label_regions(np.zeros((0, 3)), L).shape == (0,)
    with pytest.raises(InputError, match="68 finite"):
        label_regions(L[:3], L[:67])


def test_face_polygon_is_the_jaw_then_the_raised_brows():
    poly = face_polygon(L)
    assert poly.shape == (27, 2)
    np.testing.assert_array_equal(poly[:17], L[:17, :2])
    np.testing.assert_allclose(poly[17], L[26, :2] + [0, FOREHEAD_MM])


def test_region_statistics_of_known_errors():
    errors = np.array([1.0, 2.0, 3.0, np.nan, 10.0, 20.0])
    labels = np.array([0, 0, 0, 0, 4, UNLABELLED])
    stats = region_statistics(errors, labels)
    assert list(stats) == list(REGIONS)
    assert stats["mouth"] == {"median_mm": 2.0, "mean_mm": 2.0, "p95_mm": pytest.approx(2.9), "count": 3}
    assert stats["face"]["count"] == 1 and stats["face"]["median_mm"] == 10.0
    assert stats["eyes"] == {"median_mm": None, "mean_mm": None, "p95_mm": None, "count": 0}
    with pytest.raises(ValueError, match="differ in shape"):
        region_statistics(errors, labels[:-1])


def test_region_counts_on_the_synthetic_head_regression():
    """Counts of the labelled vertices of a coarse rest head: they move when the definition does."""
    from gpja.data.synthetic.head import build_head_program, extract_rest_mesh
    from gpja.data.synthetic.landmarks import rest_landmarks

    head = HeadParams()
    V, _ = extract_rest_mesh(build_head_program(head)["head"], 3.0)
    labels = label_regions(V, rest_landmarks(head))
    counts = {name: int((labels == k).sum()) for k, name in enumerate(REGIONS)}
    assert counts == {"mouth": 1000, "eyes": 247, "nose": 307, "brows": 205, "face": 3553, "outer": 21068}
