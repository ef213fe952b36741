"""The README's examples run as written (issue 31: its API example used a `scene` it never made and
read a camera raw the reader does not have)."""
from __future__ import annotations

import re

import numpy as np

from paths import REPO
from clisp.io.imageio import write_image


def test_readme_api_example_runs(tmp_path, monkeypatch) -> None:
    """The Python block after "The same as functions on NumPy arrays" runs in a folder holding a
    small photo.png, and gives what its comments say."""
    text = (REPO / "README.md").read_text()
    block = re.search(r"The same as functions on NumPy arrays:\s*```python\n(.*?)```", text, re.S).group(1)
    rng = np.random.default_rng(0)
    write_image(tmp_path / "photo.png", rng.random((48, 64, 3)), encoded=False)
    monkeypatch.chdir(tmp_path)
    names: dict = {}
    exec(compile(block, "README.md", "exec"), names)
    assert names["scene"].shape == (48, 64, 3) and names["rgb"].shape == (48, 64, 3)
    assert names["rgb"].dtype == np.float32 and names["raw"].shape == (48, 64)
    assert (tmp_path / "lms.dng").is_file()
