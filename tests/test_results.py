"""The template's lighting file: written by lighting_record, read (and checked) by read_template_lighting."""
import json

import numpy as np
import pytest

from gpja.errors import InputError
from gpja.io import write_json
from gpja.lighting import uniform_sh
from gpja.results import LIGHTING_FILE, lighting_record, read_template_lighting


def test_lighting_round_trips(tmp_path):
    sh = uniform_sh(1.0)
    sh[2] = [0.9, 0.8, 0.7]
    write_json(tmp_path / LIGHTING_FILE, lighting_record(sh, "estimated", "the convention"))
    record = json.loads((tmp_path / LIGHTING_FILE).read_text())
    assert set(record) == {"sh", "convention", "source"} and record["source"] == "estimated"
    np.testing.assert_array_equal(read_template_lighting(tmp_path), sh)


@pytest.mark.parametrize("record, message", [
    (None, "not found"),
    ({"sh": uniform_sh(1.0).tolist(), "source": "oracle"}, "source 'oracle'"),
    ({"source": "uniform"}, "the key \"sh\""),
    ({"sh": [[1, 2, 3]], "source": "uniform"}, "9 x 3"),
    ({"sh": (-uniform_sh(1.0)).tolist(), "source": "uniform"}, "positive first row"),
    ({"sh": [["a"] * 3] * 9, "source": "uniform"}, "not a 9 x 3 array"),
])
def test_bad_lighting_files_name_the_file(tmp_path, record, message):
    if record is not None:
        write_json(tmp_path / LIGHTING_FILE, record)
    with pytest.raises(InputError, match=message) as err:
        read_template_lighting(tmp_path)
    assert err.value.path == str(tmp_path / LIGHTING_FILE)


def test_lighting_record_refuses_what_it_cannot_write():
    with pytest.raises(ValueError, match="9, 3"):
        lighting_record(np.ones((4, 3)), "uniform", "")
    with pytest.raises(ValueError, match="source"):
        lighting_record(uniform_sh(1.0), "truth", "")
