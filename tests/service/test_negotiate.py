"""Content negotiation on Accept (drape.service.negotiate.choose), as RFC 9110 section 12.5.1 reads it."""

import pytest

from drape.service.errors import NotAcceptable
from drape.service.negotiate import choose

JSON, NPZ, GLB = "application/json", "application/x-npz", "model/gltf-binary"
OFFERED = [JSON, NPZ, GLB]


@pytest.mark.parametrize(("accept", "chosen"), [
    (None, JSON), ("", JSON), ("*/*", JSON),
    (GLB, GLB), (f"{NPZ}, {GLB}", NPZ), (f"{NPZ};q=0.5, {GLB}", GLB),
    ("model/*", GLB),  # a media range: the first offered type of that type (was a 406)
    ("application/*", JSON), ("application/*;q=0.2, model/*", GLB),
    (f"{GLB};q=nan, {NPZ};q=0.1", NPZ),  # an invalid q-value counts as 0
    (f"{GLB};q=2, {NPZ};q=0.1", NPZ),
    ("text/*, */*;q=0.1", JSON),
    (f"{JSON};Q=0, {NPZ}", NPZ),  # parameter names are case-insensitive (Q=0 was read as q=1)
    # the most specific matching range sets an offer's q (JSON was chosen for both: ranked by q alone)
    (f"application/*, {JSON};q=0", NPZ), (f"*/*, {JSON};q=0.5", NPZ), (f"*/*;q=0.9, {GLB}", GLB),
    ("*/*, application/*;q=0.1", GLB),
    ("*", JSON), ("*; q=.2, model/*", GLB),  # a bare "*" (Java's default Accept) is */* (it was a 406)
])
def test_accept_chooses_what_it_prefers(accept, chosen):
    assert choose(accept, OFFERED) == chosen


@pytest.mark.parametrize("accept", ["text/csv", "text/*", "model/*", f"{GLB};q=0", "*/*;q=0",
                                    f"*/*, {JSON};q=0, {NPZ};q=0"])
def test_nothing_acceptable_is_a_406_naming_accept(accept):
    with pytest.raises(NotAcceptable) as info:
        choose(accept, [JSON, NPZ])
    assert info.value.field == "Accept"
