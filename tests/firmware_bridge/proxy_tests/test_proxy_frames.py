"""Frame boundaries (firmware_bridge.proxy.frames): MAVLink 1 and 2, signed frames, unknown ids,
garbage, and a byte stream cut anywhere."""

from __future__ import annotations

import random

from firmware_bridge.proxy.frames import checksum_ok, frame_size, header, split_frames

from proxy_support import frames, mav, mavlink2


def _signed_frame() -> bytes:
    m = mav(2, 7, 8)
    m.signing.secret_key = bytes(range(32))
    m.signing.link_id = 1
    m.signing.timestamp = 1
    m.signing.sign_outgoing = True
    return bytes(m.heartbeat_encode(2, 12, 0, 0, 4).pack(m))


def test_header_and_size_of_both_versions():
    f1, f2 = frames(mav(1, 3, 4), 1)[0], frames(mav(2, 5, 6), 2)[1]
    assert frame_size(f1, 0) == len(f1) and header(f1) == (1, 0, 3, 4, 0)
    assert frame_size(f2, 0) == len(f2) and header(f2) == (2, 1, 5, 6, mavlink2.MAVLINK_MSG_ID_ATTITUDE)
    s = _signed_frame()
    assert frame_size(s, 0) == len(s) and checksum_ok(s, 0, len(s))
    assert frame_size(b"\x00", 0) == 0 and frame_size(b"\xfd", 0) == -1


def test_split_finds_every_frame_between_garbage():
    fs = frames(mav(2, 1, 1), 5) + frames(mav(1, 1, 1), 5) + [_signed_frame()]
    junk = [b"", b"\x00\x01", b"\xfd\x09", b"\xfe", b"hello"]
    buf = b"".join(junk[k % 5] + f for k, f in enumerate(fs)) + b"\xfe\x20"  # ends in a truncated frame
    spans, garbage, used = split_frames(buf)
    assert [buf[i:i + n] for i, n in spans] == fs
    assert garbage == sum(len(junk[k % 5]) for k in range(len(fs))) + 2 and used == len(buf)


def test_a_corrupted_frame_is_garbage_and_does_not_eat_the_next():
    a, b = frames(mav(2, 1, 1), 2)
    bad = bytearray(a)
    bad[-1] ^= 0xFF
    spans, garbage, _ = split_frames(bytes(bad) + b)
    assert [(bytes(bad) + b)[i:i + n] for i, n in spans] == [b] and garbage == len(a)


def test_unknown_message_ids_pass_when_a_frame_follows():
    a = frames(mav(2, 1, 1), 1)[0]
    unknown = bytearray(a)
    unknown[7:10] = (411).to_bytes(3, "little")  # PX4 sends ids the common dialect lacks
    u = bytes(unknown)
    spans, garbage, _ = split_frames(u + a)
    assert spans == [(0, len(u)), (len(u), len(a))] and garbage == 0
    spans, garbage, _ = split_frames(u + b"xyz" + a)  # not followed by a frame: not trusted
    assert [(u + b"xyz" + a)[i:i + n] for i, n in spans] == [a]


def test_a_stream_cut_anywhere_gives_the_same_frames():
    fs = frames(mav(2, 1, 1), 60) + frames(mav(1, 9, 9), 60)
    random.Random(1).shuffle(fs)
    stream = b"".join(b"\x00garbage" + f if k % 7 == 0 else f for k, f in enumerate(fs))
    rng = random.Random(2)
    buf, got = bytearray(), []
    pos = 0
    while pos < len(stream):
        step = rng.randint(1, 90)
        buf += stream[pos:pos + step]
        pos += step
        spans, _, used = split_frames(buf, final=False)
        got += [bytes(buf[i:i + n]) for i, n in spans]
        del buf[:used]
    assert got == fs and len(buf) == 0
