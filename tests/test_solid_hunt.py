"""Bug hunt in the solids path (stepped(..., solid=True), mesh.close_solid, kernels/solid.py): one failing test per
bug found.

* ``stepped(..., floor=...)`` without ``solid=True`` was refused only after the whole terrain was stepped, so a
  refusal from the stepping (the memory budget's) named something else and the misplaced ``floor`` went unsaid.
"""

from __future__ import annotations

import numpy as np
import pytest

import stepterrain as st
from stepterrain.errors import InvalidInputError


def test_a_floor_without_solid_is_refused_before_any_stepping():
    heights = st.sample_dem().heights[:40, :40]
    # a budget the stepped mesh cannot fit: the floor's refusal must come first, before the count pass
    with pytest.raises(InvalidInputError, match="floor applies only with solid=True"):
        st.stepped(heights, interval=50.0, floor=-5.0, memory_budget=1000)
    with pytest.raises(InvalidInputError, match="floor applies only with solid=True"):
        st.stepped(heights, interval=50.0, floor=-5.0, gamma=np.full((3, 3), 0.5))  # γ of the wrong shape
