import numpy as np
import pytest

from gpja.errors import InputError
from gpja.register.order import chain, plan_order, registration_tree, scan_distances
from tests.render.scenes import sphere
from tests.tolerances import EXACT_F64


def spheres(shifts_mm):
    """Unit-density spheres of radius 50 mm shifted along x: their distances grow with the shift."""
    V, _ = sphere(subdivisions=4, radius=50.0)
    return [V + np.array([s, 0.0, 0.0]) for s in shifts_mm]


def test_distances_are_symmetric_zero_on_the_diagonal_and_grow_with_the_shift():
    D = scan_distances(spheres([0.0, 1.0, 3.0]), samples=500, seed=0)
    assert np.allclose(D, D.T, atol=EXACT_F64)
    assert np.allclose(np.diag(D), 0.0)
    assert 0.0 < D[0, 1] < D[0, 2]
    # a vertex set against itself shifted by s: no vertex is farther than s from its shifted copy
    assert 0.3 < D[0, 1] <= 1.0 + EXACT_F64


def test_identical_scans_are_zero_apart():
    V = spheres([0.0])[0]
    assert scan_distances([V, V.copy()], samples=300)[0, 1] == pytest.approx(0.0, abs=EXACT_F64)


def test_the_tree_of_a_path_is_the_path_and_every_parent_comes_first():
    # A -- 1 -- B -- 1 -- C, and A--C 2.5: the spanning tree is the path, C starts from B
    names = ["A", "B", "C", "D"]
    D = np.array([[0, 1, 2.5, 4], [1, 0, 1, 3], [2.5, 1, 0, 0.5], [4, 3, 0.5, 0]], dtype=float)
    plan = registration_tree(names, D, root="A")
    assert plan["parent"] == {"A": None, "B": "A", "C": "B", "D": "C"}
    assert plan["depth"] == {"A": 0, "B": 1, "C": 2, "D": 3}
    seen = set()
    for name in plan["order"]:
        assert plan["parent"][name] is None or plan["parent"][name] in seen
        seen.add(name)
    assert chain(plan, "D") == ["A", "B", "C", "D"]


def test_the_root_may_be_any_expression():
    names = ["A", "B", "C"]
    D = np.array([[0, 1, 5], [1, 0, 1], [5, 1, 0]], dtype=float)
    assert registration_tree(names, D, root="C")["parent"] == {"C": None, "B": "C", "A": "B"}


def test_identical_scans_still_join_the_tree():
    names = ["A", "B", "C"]
    D = np.array([[0, 0, 2], [0, 0, 1], [2, 1, 0]], dtype=float)
    assert registration_tree(names, D, root="A")["parent"] == {"A": None, "B": "A", "C": "B"}


def test_plan_order_on_scans_and_its_errors():
    a, b, c = spheres([0.0, 4.0, 1.0])
    plan = plan_order({"root": a, "far": b, "near": c}, root="root", samples=400)
    assert plan["parent"] == {"root": None, "near": "root", "far": "near"}
    assert plan["distances_mm"]["root"]["far"] == plan["distances_mm"]["far"]["root"] > 0
    with pytest.raises(InputError, match="template expression"):
        plan_order({"far": b}, root="root")
    with pytest.raises(InputError, match="not in the registration tree"):
        chain(plan, "missing")


def test_plan_order_is_deterministic_for_a_seed():
    scans = dict(zip("abc", spheres([0.0, 2.0, 1.0])))
    assert plan_order(scans, "a", samples=200, seed=3) == plan_order(scans, "a", samples=200, seed=3)


def test_the_root_and_its_children_start_from_the_template():
    from gpja.register.order import start_expression

    names = ["T", "A", "B"]
    plan = registration_tree(names, np.array([[0, 1, 3], [1, 0, 1], [3, 1, 0]], dtype=float), root="T")
    assert [start_expression(plan, e) for e in names] == [None, None, "A"]
    with pytest.raises(InputError, match="not in the registration tree"):
        start_expression(plan, "C")
