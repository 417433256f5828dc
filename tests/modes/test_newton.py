"""modes/newton.py without MPI: the layout of a pair list for Newton's third law across ranks, and
the pack and unpack of the terms that travel back (the exchange itself runs in test_mpi.py)."""
import numpy as np

from dem.forces import PF_F, PF_LEN, PF_TI, PF_TJ
from modes.newton import LOCAL, TERMS, cross_layout, pack_sent, unpack_received


def test_cross_layout_groups_sent_received_local_keeping_order():
    """4 owned particles (0-3) and 3 ghosts (4, 5 owned by the block in direction 3, 6 by the one in
    direction 20). Pairs in list order (gid order): sent = those with a ghost j end, received =
    those with a ghost i end, local = both owned. Expected by hand: sent to 3: pairs 1, 6; sent to
    20: pair 2; received from 3: pairs 3, 5; from 20: pair 7; local: pairs 0, 4."""
    pi = np.array([0, 0, 1, 4, 2, 5, 3, 6])
    pj = np.array([1, 4, 6, 2, 3, 3, 5, 0])
    perm, sent, received = cross_layout(pi, pj, 4, np.array([3, 3, 20]))
    assert perm.tolist() == [1, 6, 2, 3, 5, 7, 0, 4]
    assert len(sent) == len(received) == LOCAL == 26
    assert sent[3] == 2 and sent[20] == 1 and sent.sum() == 3
    assert received[3] == 2 and received[20] == 1 and received.sum() == 3


def test_terms_pack_and_unpack_exactly():
    """The j end's force and torque and the touching flag of each sent pair arrive bit for bit in the
    receiver's pair records (the i end's torque is not sent: the receiver owns j); packing also
    zeroes the owned particles' force and torque sums (and only theirs) for the local pairs."""
    rng = np.random.default_rng(5)
    pf = rng.normal(size=(5, PF_LEN))
    on = np.array([1, 0, 1, 1, 0], dtype=np.int8)
    buf = np.zeros((3, TERMS))
    force = rng.normal(size=(6, 3))
    torque = rng.normal(size=(6, 3))
    ghost_rows = force[4:].copy(), torque[4:].copy()
    pack_sent(pf, on, 3, buf, force, torque, 4)
    assert np.all(force[:4] == 0.0) and np.all(torque[:4] == 0.0)
    assert np.array_equal(force[4:], ghost_rows[0]) and np.array_equal(torque[4:], ghost_rows[1])
    got = np.full((7, PF_LEN), 9.0)
    got_on = np.zeros(7, dtype=np.int8)
    unpack_received(buf, 2, got, got_on)
    assert np.array_equal(got[2:5, PF_F:PF_F + 3], pf[:3, PF_F:PF_F + 3])
    assert np.array_equal(got[2:5, PF_TJ:PF_TJ + 3], pf[:3, PF_TJ:PF_TJ + 3])
    assert np.all(got[2:5, PF_TI:PF_TI + 3] == 9.0) and np.all(got[[0, 1, 5, 6]] == 9.0)
    assert got_on.tolist() == [0, 0, 1, 0, 1, 0, 0]
