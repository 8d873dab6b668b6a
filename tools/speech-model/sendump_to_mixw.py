#!/usr/bin/python3
"""A PocketSphinx model's sendump as the mixture_weights file sphinxtrain's bw and map_adapt read.

Debian's en-us model ships its mixture weights only as sendump (8-bit, -log base 1.0001, shifted);
adapt.sh needs them as floats. mk_s2sendump -mwfloor 1e-8 turns the result back into a sendump
byte-identical to Debian's. The two formats:
  sendump: repeated (int32 len, string incl. NUL) header strings ended by int32 0; if
  cluster_count is 0, int32 #codewords (rows) and int32 #pdfs (senones, columns); then for each
  feature stream, for each codeword, #pdfs unsigned bytes b, weight = 1.0001 ** -(b << shift).
  mixture_weights: "s3\n" + "key value\n" lines + "endhdr\n" (padded so the data starts on a
  4-byte boundary), int32 0x11223344 byte-order mark, uint32 d1 d2 d3 n, n float32
  (senone, feature, codeword).
"""
import struct
import sys

import numpy as np


def read_sendump(path):
    data = open(path, 'rb').read()
    pos = 0
    fmt = '<I'

    def read_int():
        nonlocal pos, fmt
        n = struct.unpack_from(fmt, data, pos)[0]
        if n > 65536 and fmt == '<I':
            fmt = '>I'
            n = struct.unpack_from(fmt, data, pos)[0]
        pos += 4
        return n

    def read_str():
        nonlocal pos
        n = read_int()
        if n == 0:
            return None
        s = data[pos:pos + n - 1].decode('latin-1')
        pos += n
        return s

    read_str()  # title
    attrs = {}
    while True:
        h = read_str()
        if h is None:
            break
        parts = h.split()
        if len(parts) == 2 and parts[1].lstrip('-').isdigit():
            attrs[parts[0]] = int(parts[1])
    shift = attrs.get('mixw_shift', 10)
    n_feat = attrs.get('feature_count', 1)
    if attrs.get('cluster_count', 0) != 0:
        raise SystemExit('clustered sendump not supported')
    if attrs.get('cluster_bits', 8) != 8:
        raise SystemExit('only 8-bit sendump supported')
    rows = read_int()  # codewords
    cols = read_int()  # senones
    need = n_feat * rows * cols
    if len(data) - pos != need:
        raise SystemExit(f'sendump size mismatch: {len(data) - pos} bytes of data, expected {need}')
    q = np.frombuffer(data, dtype=np.uint8, count=need, offset=pos).reshape(n_feat, rows, cols)
    logw = -(q.astype(np.float64) * (1 << shift)) * np.log(1.0001)
    w = np.exp(logw).transpose(2, 0, 1)  # senone, feature, codeword
    w /= w.sum(axis=2, keepdims=True)
    print(f'sendump: {cols} senones, {n_feat} features, {rows} codewords, shift {shift}')
    return w


def write_mixw(path, w):
    d1, d2, d3 = w.shape
    with open(path, 'wb') as f:
        head = b's3\nversion 1.0\n'
        pad = (len(head) + len(b'endhdr\n')) & 3
        if pad:
            head += b' ' * (4 - pad)
        head += b'endhdr\n'
        f.write(head)
        f.write(struct.pack('<i', 0x11223344))
        f.write(struct.pack('<IIII', d1, d2, d3, d1 * d2 * d3))
        f.write(w.astype('<f4').tobytes())


if __name__ == '__main__':
    if len(sys.argv) != 3:
        raise SystemExit('usage: sendump2mixw.py SENDUMP MIXTURE_WEIGHTS')
    write_mixw(sys.argv[2], read_sendump(sys.argv[1]))
