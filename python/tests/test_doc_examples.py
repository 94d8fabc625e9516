"""The Python examples of the docs run as written (docs/README.md, "Contributor notes"): every
```python block of README.md and docs/*.md marked `<!-- run -->` on the line before it is executed
on its own, in the source tree (relative paths such as scenarios/paper.yaml resolve there), with
numpy as np and ukdyn imported. The other Python blocks continue an earlier one (q, qd, tau, a
law) and are not run."""
import contextlib
import re

import numpy as np
import pytest

import ukdyn
from conftest import SOURCE


def marked_blocks():
    pages = [SOURCE / "README.md"] + sorted((SOURCE / "docs").glob("*.md"))
    out = []
    for page in pages:
        lines = page.read_text().split("\n")
        i = 0
        while i < len(lines):
            if lines[i].startswith("```python"):
                j = i + 1
                while not lines[j].startswith("```"):
                    j += 1
                k = i - 1
                while k >= 0 and not lines[k].strip():
                    k -= 1
                if k >= 0 and re.fullmatch(r"\s*<!--\s*run\s*-->\s*", lines[k]):
                    out.append(pytest.param("\n".join(lines[i + 1:j]),
                                            id=f"{page.name}:{i + 1}"))
                i = j
            i += 1
    return out


BLOCKS = marked_blocks()


def test_some_blocks_are_marked():
    assert len(BLOCKS) >= 3, "the <!-- run --> markers of docs/python.md were not found"


@pytest.mark.parametrize("code", BLOCKS)
def test_block_runs(code, tmp_path):
    if "ukdyn.optimize(" in code and not ukdyn.ipopt_available():
        pytest.skip("built without IPOPT")
    with contextlib.chdir(SOURCE):
        exec(compile(code, "<doc block>", "exec"), {"np": np, "ukdyn": ukdyn, "__name__": "doc"})
