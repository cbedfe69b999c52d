"""tests/e2e/test_seal_dpus.py's tests that start no skel-dpu (it says what they check)."""

from __future__ import annotations

import os
import time

import skelmsg
from skeleton.analysis.read.seal import Signer, Verdict, Verifier, split
from skelmsg import contract


# --- the Python side alone ---------------------------------------------------------------
def test_a_seal_is_checked_for_key_integrity_and_freshness() -> None:
    key, other = os.urandom(32), os.urandom(32)
    signer = Signer(key, sender=7)
    message = skelmsg.command_t().encode()
    sealed = signer.seal(contract.COMMAND_CHANNEL, message)
    assert len(sealed) == len(message) + contract.SEAL_BYTES
    assert bytes(split(sealed)[0]) == message
    check = Verifier(key).check
    assert check(contract.COMMAND_CHANNEL, sealed)[0] is Verdict.GENUINE
    assert check(contract.COMMAND_CHANNEL, sealed)[0] is Verdict.REPLAYED        # the same counter again
    later = signer.seal(contract.COMMAND_CHANNEL, message)
    assert check(contract.CONFIG_CHANNEL, later)[0] is Verdict.FORGED           # the channel is signed
    flipped = bytearray(later)
    flipped[3] ^= 1
    assert check(contract.COMMAND_CHANNEL, bytes(flipped))[0] is Verdict.FORGED
    assert Verifier(other).check(contract.COMMAND_CHANNEL, later)[0] is Verdict.FORGED
    assert check(contract.COMMAND_CHANNEL, message)[0] is Verdict.UNSIGNED
    assert Verifier(None).check(contract.COMMAND_CHANNEL, later)[0] is Verdict.SIGNED
    assert Verifier(None).check(contract.COMMAND_CHANNEL, message)[0] is Verdict.GENUINE
    # a sender not heard before, older than the freshness window: a replay of old traffic
    minutes_ago = time.time_ns() - (contract.SEAL_FRESH_S + 5) * 10**9
    old = Signer(key, sender=8, clock=lambda: minutes_ago).seal(contract.COMMAND_CHANNEL, message)
    stale_seal = split(old)[1]
    assert stale_seal is not None and stale_seal.counter < time.time_ns() - contract.SEAL_FRESH_S * 10**9
    assert Verifier(key).check(contract.COMMAND_CHANNEL, old)[0] is Verdict.REPLAYED
