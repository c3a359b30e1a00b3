"""LZF (liblzf) compression, the codec of PCD ``binary_compressed`` files, in plain Python.

No maintained LZF binding is on PyPI; the format is small: a control byte below 32 starts a
run of ctrl+1 literal bytes, otherwise its top 3 bits are a match length (7 = look at the next
byte too) and the rest with the next byte an offset back into the output.
"""

from __future__ import annotations

_MAX_OFFSET = 1 << 13
_MAX_MATCH = 264
_MAX_LITERAL = 32


class LzfError(ValueError):
    """A corrupt or truncated LZF stream."""


def decompress(data: bytes, size: int) -> bytes:
    """Inflate ``data`` to exactly ``size`` bytes; LzfError when the stream is damaged."""
    out = bytearray()
    i, n = 0, len(data)
    while i < n:
        ctrl = data[i]
        i += 1
        if ctrl < 32:
            run = ctrl + 1
            if i + run > n:
                raise LzfError(f"literal run of {run} bytes at {i - 1} passes the end of the data")
            out += data[i : i + run]
            i += run
            continue
        length = ctrl >> 5
        if length == 7:
            if i >= n:
                raise LzfError(f"match at {i - 1} is cut off")
            length += data[i]
            i += 1
        if i >= n:
            raise LzfError(f"match at {i - 1} is cut off")
        offset = ((ctrl & 0x1F) << 8) + data[i] + 1
        i += 1
        length += 2
        start = len(out) - offset
        if start < 0:
            raise LzfError(f"match at {i - 2} refers {offset} bytes back, before the start")
        if offset >= length:
            out += out[start : start + length]
        else:
            for k in range(length):
                out.append(out[start + k])
        if len(out) > size:
            break
    if len(out) != size:
        raise LzfError(f"inflates to {len(out)} bytes, the header says {size}")
    return bytes(out)


def compress(data: bytes) -> bytes:
    """Deflate ``data`` greedily with a 3-byte hash of last positions (liblzf's scheme)."""
    out = bytearray()
    literal = bytearray()
    last: dict[bytes, int] = {}
    i, n = 0, len(data)

    def flush() -> None:
        for k in range(0, len(literal), _MAX_LITERAL):
            chunk = literal[k : k + _MAX_LITERAL]
            out.append(len(chunk) - 1)
            out.extend(chunk)
        literal.clear()

    while i < n:
        key = data[i : i + 3]
        ref = last.get(key) if len(key) == 3 else None
        last[key] = i
        if ref is not None and i - ref <= _MAX_OFFSET:
            limit = min(_MAX_MATCH, n - i)
            length = 3
            while length < limit and data[ref + length] == data[i + length]:
                length += 1
            flush()
            offset = i - ref - 1
            code = length - 2
            if code < 7:
                out.append((code << 5) | (offset >> 8))
            else:
                out.append((7 << 5) | (offset >> 8))
                out.append(code - 7)
            out.append(offset & 0xFF)
            i += length
            continue
        literal.append(data[i])
        i += 1
    flush()
    return bytes(out)
