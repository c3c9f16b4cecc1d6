"""Remembering results by the content of their arguments (stictiondiag.core.memo)."""

from __future__ import annotations

import numpy as np
import pytest

from stictiondiag.core.memo import content_key, memo_by_content, memo_scope


@pytest.fixture
def scope():
    with memo_scope():
        yield


def _counting(maxsize: int = 2):
    calls: list[int] = []

    @memo_by_content(maxsize)
    def f(x, y=None, *, scale: float = 1.0):
        calls.append(1)
        if scale < 0:
            raise ValueError("negative scale")
        return float(np.sum(x)) * scale + (0.0 if y is None else float(np.sum(y)))

    return f, calls


def test_equal_content_in_another_array_is_remembered(scope):
    f, calls = _counting()
    x = np.arange(10.0)
    assert f(x) == 45.0
    assert f(x.copy()) == 45.0  # another object, the same numbers
    assert len(calls) == 1


def test_a_change_of_one_value_is_computed_again(scope):
    f, calls = _counting()
    x = np.arange(10.0)
    f(x)
    y = x.copy()
    y[3] += 1e-12  # the smallest change still changes the bytes
    assert f(y) == pytest.approx(45.0, abs=1e-9)
    assert len(calls) == 2


def test_defaults_given_or_left_out_make_one_key(scope):
    f, calls = _counting()
    x = np.ones(4)
    f(x)
    f(x, None, scale=1.0)
    assert len(calls) == 1
    f(x, scale=2.0)
    assert len(calls) == 2


def test_dtype_and_shape_are_part_of_the_key():
    a = np.zeros(4)
    assert content_key({"x": a}) != content_key({"x": a.reshape(2, 2)})
    assert content_key({"x": a}) != content_key({"x": a.astype(np.float32)})


def test_other_argument_types_are_not_remembered(scope):
    f, calls = _counting()
    f([1.0, 2.0])  # a list: passed through, computed every time
    f([1.0, 2.0])
    assert len(calls) == 2


def test_oldest_result_goes_first_and_exceptions_are_not_kept(scope):
    f, calls = _counting(maxsize=2)
    a, b, c = np.zeros(2), np.ones(2), np.full(2, 2.0)
    f(a), f(b), f(c)  # a is forgotten
    f(c)
    assert len(calls) == 3
    f(a)
    assert len(calls) == 4
    with pytest.raises(ValueError):
        f(a, scale=-1.0)
    with pytest.raises(ValueError):
        f(a, scale=-1.0)
    assert len(calls) == 6


def test_identification_repeated_on_the_same_signals_is_not_redone():
    """The loop type from the data and the replay identify the controller and the
    process from the same signals: the second call returns the first call's result,
    and a call on other data computes its own."""
    from stictiondiag.identification.controller import identify_controller
    from stictiondiag.identification.process import identify_process
    from stictiondiag.models.loops import LOOP_PARAMETERS, simulate_loop

    conc = LOOP_PARAMETERS["concentration"]
    dt = 1.0
    s = simulate_loop(
        conc["process"],
        conc["controller"],
        duration=3000.0,
        dt=dt,
        S=5.0,
        J=2.0,
        sp=np.full(3000, 10.0),
        op_bias=40.0,
        pv_bias=10.0,
    )
    sp, pv, op = np.asarray(s.sp), np.asarray(s.pv), np.asarray(s.op)
    with memo_scope():
        first = identify_controller(sp, pv, op, dt)
        again = identify_controller(sp.copy(), pv.copy(), op.copy(), dt)
        assert again is first
        assert identify_controller(sp, pv, op + 1e-9, dt) is not first
        pf = identify_process(np.asarray(s.mv), pv, dt, integrating=False)
        mv = np.asarray(s.mv).copy()
        same = identify_process(mv, pv, dt, drift_time_constant=None, integrating=False)
        assert same is pf
    # Outside a scope every call computes: nothing outlives the analysis.
    assert identify_controller(sp, pv, op, dt) is not first


def test_nothing_is_remembered_outside_a_scope():
    f, calls = _counting()
    x = np.arange(3.0)
    f(x), f(x)
    assert len(calls) == 2
    with memo_scope():
        f(x), f(x)
        with memo_scope():  # a nested scope shares the outer one
            f(x)
    assert len(calls) == 3
    f(x)
    assert len(calls) == 4
