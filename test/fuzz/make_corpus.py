#!/usr/bin/env python3
"""Writes the seed corpus of the safetensors/JSON fuzz target into
test/data/fuzz_corpus/: small valid files (every dtype, metadata with a model
config, empty tensors) and one invalid file per validation rule, plus a few
plain JSON texts. Deterministic; rerun after changing the rules."""
import json
import os
import struct
import sys

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "data", "fuzz_corpus")


def image(header, data=b"", pad=True):
    h = header if isinstance(header, bytes) else header.encode()
    if pad:
        h += b" " * ((8 - len(h) % 8) % 8)
    return struct.pack("<Q", len(h)) + h + data


def st(entries, metadata=None, data_size=None):
    """entries: name -> (dtype, shape, begin, end)."""
    obj = {}
    if metadata is not None:
        obj["__metadata__"] = metadata
    end = 0
    for k, (dt, shape, b, e) in entries.items():
        obj[k] = {"dtype": dt, "shape": shape, "data_offsets": [b, e]}
        end = max(end, e)
    size = end if data_size is None else data_size
    return image(json.dumps(obj), bytes((i * 37) & 0xFF for i in range(size)))


CONFIG = json.dumps({
    "model": "AsymmetricCroCo3DStereo",
    "dust3r": {"enc_embed_dim": 32, "depth_mode": ["exp", "-inf", "inf"],
               "norm_layer": "LayerNorm(eps=1e-6)", "mask_ratio": 0.9,
               "dpt_head": {"hooks": [0, 5, 7, 10], "use_bn": False}}},
    sort_keys=True)

FILES = {
    "valid_two.safetensors": st({"w": ("F32", [2, 2], 8, 24), "n": ("I64", [1], 0, 8)},
                                {"config": CONFIG}),
    "valid_all_dtypes.safetensors": st({
        "a": ("I64", [2], 0, 16), "b": ("F32", [3], 16, 28), "c": ("F16", [2], 28, 32),
        "d": ("BF16", [1, 1], 32, 34), "e": ("F32", [0, 7], 34, 34), "s": ("F32", [], 36, 40),
        "f": ("F64", [1], 40, 48), "u": ("U8", [3], 48, 51)},
        {"k": "v", "esc": "\u00e9\U0001F600\n\"\\"}),
    "valid_empty.safetensors": image("{}"),
    "valid_metadata_only.safetensors": image('{"__metadata__": {"case": "x"}}'),
    "valid_unicode_escapes.safetensors": image(
        '{"__metadata__": {"k": "\\u00e9\\ud83d\\ude00\\t\\/"}, "t\\u0041": '
        '{"dtype": "F16", "shape": [1], "data_offsets": [0, 2]}}', b"\x00\x3c"),
    "bad_dtype.safetensors": st({"w": ("C64", [1], 0, 8)}),
    "bad_shape_mismatch.safetensors": st({"w": ("F32", [2, 3], 0, 20)}),
    "bad_offset_past_end.safetensors": st({"w": ("F32", [4], 0, 16)}, data_size=8),
    "bad_overlap.safetensors": st({"a": ("F32", [4], 0, 16), "b": ("F32", [4], 8, 24)}),
    "bad_negative_dim.safetensors": st({"w": ("F32", [2, -1], 0, 0)}),
    "bad_numel_overflow.safetensors": st({"w": ("I64", [4294967296, 4294967296], 0, 0)}),
    "bad_metadata_value.safetensors": image('{"__metadata__": {"k": 1}}'),
    "bad_duplicate_name.safetensors": image(
        '{"a": {"dtype": "F32", "shape": [1], "data_offsets": [0, 4]}, '
        '"a": {"dtype": "F32", "shape": [1], "data_offsets": [4, 8]}}', b"\x00" * 8),
    "bad_json.safetensors": image('{"a": {"dtype": "F32", "shape": [1,], "data_offsets": [0, 4]}}',
                                  b"\x00" * 4),
    "bad_header_length.safetensors": struct.pack("<Q", 1 << 40) + b"{}",
    "bad_truncated.safetensors": st({"w": ("F32", [8], 0, 32)})[:-5],
    "bad_short.bin": b"\x08\x00\x00",
    "json_config.json": CONFIG.encode(),
    "json_values.json": b'[0, -0.0, 1e-400, 123456789012345678901234, 1.5E+3, true, false, null,'
                        b' "\\u0000\\b\\f\\n\\r\\t\\"\\\\\\/", {"": []}, [[[]]]]',
    "json_bad_surrogate.json": b'["\\ud800x"]',
}


def main():
    os.makedirs(OUT, exist_ok=True)
    for name, data in sorted(FILES.items()):
        with open(os.path.join(OUT, name), "wb") as f:
            f.write(data)
    print("wrote %d files to %s" % (len(FILES), os.path.normpath(OUT)), file=sys.stderr)


if __name__ == "__main__":
    main()
