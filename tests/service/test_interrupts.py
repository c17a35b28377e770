"""Ctrl-C held back while one unit of output is written, then delivered as before."""

from __future__ import annotations

import signal

import pytest

from service.interrupts import interrupts_held, raise_if_interrupted


def test_sigint_is_held_until_the_block_is_done_then_delivered() -> None:
    reached_the_end = False
    with pytest.raises(KeyboardInterrupt), interrupts_held():
        signal.raise_signal(signal.SIGINT)
        reached_the_end = True
    assert reached_the_end
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_nested_blocks_deliver_the_interrupt_once_at_the_outer_end() -> None:
    steps: list[str] = []
    with pytest.raises(KeyboardInterrupt), interrupts_held():
        with interrupts_held():
            signal.raise_signal(signal.SIGINT)
            steps.append("inner done")
        steps.append("outer done")
    assert steps == ["inner done", "outer done"]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_a_block_without_ctrl_c_changes_nothing() -> None:
    with interrupts_held():
        pass
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_a_ctrl_c_wrapped_by_compiled_code_is_raised_again() -> None:
    try:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as interrupt:
            raise SystemError("returned a result with an exception set") from interrupt
    except SystemError as wrapped:
        with pytest.raises(KeyboardInterrupt):
            raise_if_interrupted(wrapped)


def test_other_errors_are_left_to_the_caller() -> None:
    raise_if_interrupted(ValueError("a bad frame"))
