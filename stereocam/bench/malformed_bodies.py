"""Malformed JSON bodies on every endpoint that reads one, and malformed YAML calibrations."""
from __future__ import annotations

import contextlib
import json
import random
from typing import Any, Dict, List, Optional, Sequence, Tuple

from .alias_bomb import alias_bombs, billion_laughs
from .malformed_case import ANSWERED, CaseBuilder

JSON_ENDPOINTS = [(b"PUT", b"/api/source"), (b"PUT", b"/api/cameras"), (b"PUT", b"/api/calibration/session"),
                  (b"POST", b"/api/calibration/compute"), (b"POST", b"/api/calibration/apply"),
                  (b"POST", b"/api/virtual-camera"), (b"PUT", b"/api/calibration")]


def json_cases(b: CaseBuilder) -> None:
    deep = [(b"[" * n + b"]" * n) for n in (100, 1000, 100_000)] + [(b'{"a":' * n + b"1" + b"}" * n)
                                                                   for n in (1000, 50_000)]
    broken = [b"{", b"}", b"{\"source\":}", b"[1,]", b"{'source': 'live'}", b"{\"source\": \"live\",}",
              b"{} x", b"\xff\xfe", b'{"source": "\xff"}', b"NaN", b"Infinity", b"-", b"1" * 5000,
              b"\"" + b"a" * 100_000,
              b"{\"a\": 1e99999}", b"{\"a\": " + b"9" * 5000 + b"}", b"\x00", b"   ", b"\t\n", b"[" * 50,
              b"{\"a\": \"\\ud800\"}", b"{\"a\" 1}", b"{\"a\": tru}", b"{\"a\": nul}", b"{{}}", b"[}",
              b"/* comment */ {}", b"{\"a\": 0x10}", b"{\"a\": .5}", b"{\"a\": 01}", b"{\"a\": +1}",
              b"{" + b",".join(b'"k%d": %d' % (i, i) for i in range(20_000)) + b"}"]
    wrong_top = [b"[]", b"\"live\"", b"1", b"true", b"null", b"[{\"source\": \"live\"}]", b"3.5"]
    lenient = ['{"source": "live"}'.encode("utf-16"), '{"source": "live"}'.encode("utf-32"),
               b"\xef\xbb\xbf{\"source\": \"live\"}"]  # JSON in another encoding: Python reads it
    for method, path in JSON_ENDPOINTS:
        for body in lenient:
            b.request("json", f"{path.decode()} {body[:30]!r}", method, path, body, ANSWERED,
                      headers=[(b"Content-Type", b"application/json")])
        for body in deep + broken + wrong_top:
            if path == b"/api/calibration/compute" and body == b"null":
                continue  # "no body" and null: compute reads both as "no settings" (then 422, no pairs)
            b.request("json", f"{path.decode()} {body[:30]!r}", method, path, body,
                      headers=[(b"Content-Type", b"application/json")])
        for ctype in (b"text/html", b"application/json; charset=bogus", b"application/json; charset=utf-16",
                      b"application/xml", b"\xff"):
            b.request("json", f"{path.decode()} as {ctype!r}", method, path, b"{\"x\": 1}",
                      headers=[(b"Content-Type", ctype)])
    values = [b"1", b"null", b"[]", b"{}", b"true", b"\"\"", b"\"x\"", b"1.5", b"-1", b"NaN", b"Infinity",
              b"-Infinity", b"1e309", b"\"" + b"x" * 10000 + b"\"", b"[\"live\"]", b"{\"a\": 1}", b"0",
              b"100000000000000000000000000000"]
    endpoint_fields = {
        (b"PUT", b"/api/source"): {b"source": values + [b"\"LIVE\"", b"\"live \"", b"\"live\\u0000\"",
                                                          b"\"virtual\\n\""]},
        (b"PUT", b"/api/cameras"): {
            b"gain": [v for v in values if v not in (b"1", b"1.5")] + [b"\"2\"", b"99", b"0.5", b"4.0001"],
            b"exposure_us": [v for v in values if v not in (b"1", b"1.5", b"0")] + [b"\"100\"", b"1e12"],
            b"flip_h": [b"\"yes\"", b"1", b"0", b"null", b"0.5", b"[]"], b"flip_v": [b"2", b"\"no\"", b"{}"],
            b"aec": [b"\"on\"", b"1", b"[]"], b"agc": [b"2", b"\"off\"", b"null"],
            b"test_pattern": [b"5", b"\"nope\"", b"[]", b"{\"a\": 1}", b"true", b"\"" + b"p" * 5000 + b"\""],
            b"camera": [b"\"middle\"", b"1", b"null", b"[\"left\"]", b"\"LEFT\"", b"\"\""],
            b"bogus": [b"1"]},
        (b"PUT", b"/api/calibration/session"): {
            b"pattern": [b"\"0x0\"", b"\"9x6x3\"", b"\"x\"", b"96", b"null", b"\"-9x6\"", b"\"9x-6\"",
                         b"\"99999999999999999999x6\"", b"\"\"", b"[9, 6]", b"\"1000x1000\""],
            b"square_mm": [b"0", b"-1", b"1001", b"NaN", b"Infinity", b"\"25\"", b"null", b"true", b"[]",
                           b"1e309"],
            b"alpha": [b"-0.1", b"1.1", b"NaN", b"\"0.5\"", b"null", b"true", b"Infinity", b"[]",
                       b"-Infinity"],
            b"bogus": [b"1", b"null"]},
        (b"POST", b"/api/calibration/compute"): {
            b"alpha": [b"2", b"NaN", b"\"x\"", b"-1"], b"pattern": [b"5", b"\"x\"", b"null"],
            b"square_mm": [b"0", b"\"25\"", b"-5"], b"bogus": [b"1", b"{}"]},
        (b"POST", b"/api/calibration/apply"): {
            b"id": [b"1", b"null", b"[]", b"{}", b"\"\"", b"\"" + b"x" * 1000 + b"\"", b"\"../x\"", b"true"],
            b"bogus": [b"1"]},
        (b"PUT", b"/api/calibration"): {b"yaml": [b"1", b"null", b"[]", b"{}", b"true", b"\"\"", b"\" \""],
                                        b"yml": [b"\"x\""], b"bogus": [b"\"x\""]},
    }
    for (method, path), fields in endpoint_fields.items():
        for name, options in fields.items():
            for value in options:
                body = b"{\"" + name + b"\": " + value + b"}"
                b.request("json", f"{path.decode()} {body[:40]!r}", method, path, body,
                          headers=[(b"Content-Type", b"application/json")])
    for method, path in ((b"PUT", b"/api/cameras"), (b"PUT", b"/api/calibration/session")):  # one bad of many
        body = (b"{\"gain\": 2.0, \"flip_h\": \"maybe\"}" if b"cameras" in path
                else b"{\"alpha\": 0.5, \"square_mm\": -3}")
        b.request("json", f"{path.decode()} good and bad fields", method, path, body,
                  headers=[(b"Content-Type", b"application/json")])


def _with_field(doc: Dict[str, Any], path: Sequence[str], raw: str) -> str:
    """The calibration ``doc`` as YAML with the value at ``path`` written as the YAML text ``raw``."""
    import yaml

    copy = json.loads(json.dumps(doc))
    node = copy
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = "@@HOSTILE@@"
    dumper = getattr(yaml, "CSafeDumper", yaml.SafeDumper)
    return str(yaml.dump(copy, Dumper=dumper, sort_keys=False)).replace("'@@HOSTILE@@'", raw)


# Values that no field of a calibration takes, each refused while the file is read (before the
# line-buffer check, which takes seconds): every path of the model and rectification gets them.
HOSTILE_VALUES = ["!!binary AAAA", "!!set {a, b}", "null", "true", "[]", "{}", "'x'", "2001-01-01",
                  "[[1, 2], [3, 4]]", "{a: 1}", "[1, 'a', null]", "[[1, 2, 3], [4, 5], [6]]", "!!bool maybe",
                  "!!int xyz", "1" * 5000, "0x" + "f" * 5000, "1.0e+400", ".nan", "-.inf", "!!float abc",
                  "!!timestamp 2001-13-45", "!!python/object/apply:os.system ['true']",
                  "!!python/name:os.system",
                  "!custom 5", "[.nan, .nan, .nan, .nan]", "[[1.0e+308, 0, 0], [0, 1.0e+308, 0], [0, 0, 1]]",
                  "*undefined", "&anchor [1, 2]"]


def yaml_cases(b: CaseBuilder, calibration_yaml: Optional[str], rng: random.Random) -> None:
    import yaml

    good = calibration_yaml or "schema_version: 1\nmodel: {}\n"
    texts: List[Tuple[str, str]] = []
    for levels, width in ((12, 10), (9, 9), (30, 2), (4, 1000)):
        texts.append((f"alias bomb {width}^{levels}", billion_laughs(levels, width)))
    texts.extend((f"{name} alias bomb", text) for name, text in alias_bombs(good).items())
    texts += [("an alias in K1", good.replace("K1:", "K0: &k [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\n  K1:", 1)
               .replace("K2:", "K2: *k\n  K3:", 1)),
              ("a merge key", "base: &b {schema_version: 1}\n<<: *b\n"),
              ("an alias as a key", "a: &k key\n*k : 1\n"),
              ("a self-referencing alias", "a: &a [*a]\n")]
    for depth in (33, 100, 1000, 100_000):
        texts.append((f"flow lists {depth} deep", "deep: " + "[" * depth + "]" * depth + "\n"))
        texts.append((f"flow maps {depth} deep", "deep: " + "{a: " * depth + "1" + "}" * depth + "\n"))
    for depth in (40, 300):
        texts.append((f"block maps {depth} deep", "".join(f"{' ' * i}k:\n" for i in range(depth))
                      + " " * depth + "v\n"))
        texts.append((f"block lists {depth} deep", "".join(f"{' ' * (2 * i)}- \n" for i in range(depth))
                      + " " * (2 * depth) + "- x\n"))
    texts.append(("a deep value in a calibration", good + "deep: " + "[" * 5000 + "]" * 5000 + "\n"))
    texts += [("tabs", "schema_version: 1\nmodel:\n\tK1: 1\n"),
              ("an unclosed list", "schema_version: [1, 2\n"),
              ("bad indentation", "schema_version: 1\n  model: 2\n model: 3\n"),
              ("two documents", good + "---\n" + good), ("an end marker only", "...\n"),
              ("a NUL", "schema_version: 1\nmodel: \x00\n"), ("a bell", "schema_version: 1\x07\n"),
              ("a BOM and broken YAML", "\ufeffschema_version: [\n"),
              ("comments only", "# nothing\n# here\n"),
              ("a scalar", "calibration\n"), ("a list", "- 1\n- 2\n"), ("a number", "42\n"),
              ("over 256 KiB", "schema_version: 1\npad: '" + "x" * 300_000 + "'\n"),
              ("a 4 MB line", "x" * 4_200_000), ("mapping values in a scalar", "a: b: c\n"),
              ("an unhashable key", "? [a, b]\n: c\n"), ("a duplicate anchor", "a: &x 1\nb: &x 2\n"),
              ("a directive", "%YAML 9.9\n--- 1\n"), ("a tag directive", "%TAG ! tag:evil,2000:\n--- !x 1\n"),
              ("schema_version 2", good.replace("schema_version: 1", "schema_version: 2", 1)),
              ("schema_version 10**100",
               good.replace("schema_version: 1", "schema_version: 1" + "0" * 100, 1)),
              ("schema_version true", good.replace("schema_version: 1", "schema_version: true", 1)),
              ("no schema_version", good.replace("schema_version: 1", "schema: 1", 1)),
              ("no model", "schema_version: 1\n"),
              ("a model that is a list", "schema_version: 1\nmodel: [1]\n")]
    if calibration_yaml is not None:
        doc = yaml.safe_load(calibration_yaml)
        paths: List[Tuple[str, ...]] = [(section, key) for section in ("model", "rectification")
                                        for key in doc.get(section) or {}]
        paths += [(key,) for key in ("model", "rectification", "schema_version") if key in doc]
        for path in paths:
            original: Any = doc
            for key in path:
                original = original[key]
            for raw in rng.sample(HOSTILE_VALUES, 9):
                with contextlib.suppress(yaml.YAMLError, ValueError, KeyError, TypeError):
                    if yaml.safe_load(raw) == original:
                        continue  # the value it has: a calibration the daemon takes (and seconds to check)
                texts.append((f"{'.'.join(path)}: {raw[:30]}", _with_field(doc, path, raw)))
    for name, text in texts:
        data = text.encode("utf-8")
        b.request("yaml", f"{name} (application/yaml)", b"PUT", b"/api/calibration", data,
                  headers=[(b"Content-Type", b"application/yaml")])
        if len(data) < 300_000 and rng.random() < 0.3:
            b.request("yaml", f"{name} (text/plain)", b"PUT", b"/api/calibration", data,
                      headers=[(b"Content-Type", b"text/plain")])
        if len(data) < 300_000 and rng.random() < 0.3:
            b.request("yaml", f"{name} (JSON)", b"PUT", b"/api/calibration",
                      json.dumps({"yaml": text}).encode(), headers=[(b"Content-Type", b"application/json")])
    for body in (b"\xff\xfe\x00", b"schema_version: 1\n\x80\x81", "schéma: 1".encode("latin-1"), b"",
                 "schema_version: 1".encode("utf-16")):
        b.request("yaml", f"not UTF-8: {body[:20]!r}", b"PUT", b"/api/calibration", body,
                  headers=[(b"Content-Type", b"application/yaml")])
