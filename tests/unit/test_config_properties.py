"""Property-based tests (hypothesis) over every numeric case key: bad input never escapes as
anything but a one-line CaseError naming the key."""

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cfddem.config import SCHEMA, Key, build_case
from cfddem.errors import CaseError


def _numeric_keys():
    out = []

    def walk(sec, prefix):
        for k, v in sec.items():
            if isinstance(v, dict):
                walk(v, f"{prefix}{k}.")
            elif isinstance(v, Key) and v.type in ("float", "int"):
                out.append((f"{prefix}{k}", v))

    walk(SCHEMA, "")
    return out


NUMERIC = _numeric_keys()


def _nest(dotted, value):
    d = {}
    cur = d
    parts = dotted.split(".")
    for p in parts[:-1]:
        cur = cur.setdefault(p, {})
    cur[parts[-1]] = value
    return d


def _outside(spec: Key, x: float) -> bool:
    if spec.lo is not None and (x < spec.lo or (spec.lo_open and x == spec.lo)):
        return True
    if spec.hi is not None and (x > spec.hi or (spec.hi_open and x == spec.hi)):
        return True
    return False


def test_there_are_many_numeric_keys():
    assert len(NUMERIC) >= 40


@settings(max_examples=300, deadline=None)
@given(idx=st.integers(0, len(NUMERIC) - 1),
       value=st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**6, 10**6),
                       st.text(max_size=5), st.booleans(), st.lists(st.integers(), max_size=2)))
def test_any_value_is_accepted_or_refused_with_the_key(idx, value):
    key, spec = NUMERIC[idx]
    try:
        c = build_case(_nest(key, value))
    except CaseError as e:
        msg = str(e)
        assert "\n" not in msg
        if e.key != key:
            # only consistency checks may name another key, and only for an accepted value
            assert isinstance(value, (int, float)) and not isinstance(value, bool)
            assert not (isinstance(value, float) and math.isnan(value))
            assert not _outside(spec, float(value))
        return
    # accepted: the value is in range and of the right type
    assert not isinstance(value, (bool, str, list))
    if spec.type == "int":
        assert isinstance(value, int)
    v = c.resolved
    for p in key.split("."):
        v = v[p]
    assert v == value
    assert not _outside(spec, float(value))


@settings(max_examples=100, deadline=None)
@given(idx=st.integers(0, len(NUMERIC) - 1), delta=st.floats(1e-6, 1e6))
def test_out_of_range_always_names_the_key(idx, delta):
    key, spec = NUMERIC[idx]
    bad = []
    if spec.lo is not None:
        bad.append(spec.lo - delta)
        if spec.lo_open:
            bad.append(spec.lo)
    if spec.hi is not None and math.isfinite(spec.hi):
        bad.append(spec.hi + delta)
        if spec.hi_open:
            bad.append(spec.hi)
    for b in bad:
        val = int(math.floor(b)) if spec.type == "int" else b
        if not _outside(spec, float(val)):
            continue
        with pytest.raises(CaseError) as e:
            build_case(_nest(key, val))
        assert e.value.key == key
        assert "out of range" in str(e.value)
