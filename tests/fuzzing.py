"""The fuzzing harness of ``tests/test_fuzz_*.py`` (issue 29, item 1).

Every reader and decoder of makeway is called on generated inputs: valid files mutated with some
knowledge of their structure (fields dropped or swapped, NaN, infinities, huge numbers, wrong
columns, lines cut, BOMs, other encodings, YAML trees with keys removed or values of the wrong type,
bytes flipped, files truncated) and plain random bytes. The contract (docs/cli_contract.md): every
input ends in a result or in one :class:`~makeway.errors.InputError` (or the error type a reader
documents) whose message is one line naming the file — never another exception, never a hang.

:func:`check_reader` runs one call under that contract and counts it per reader; the counts are
written as JSON at exit when ``MAKEWAY_FUZZ_COUNTS`` names a file (``benchmarks/bench_fuzz.py``).
The budget comes from the hypothesis profile (``MAKEWAY_FUZZ_PROFILE``: ``ci``, the default, or
``long``; registered in ``tests/conftest.py``): :func:`budget` scales its ``max_examples`` per reader.
"""

from __future__ import annotations

import atexit
import faulthandler
import json
import os
import signal
import string
import warnings
from collections import Counter, defaultdict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from types import FrameType
from typing import Any, TypeVar

import yaml
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

from makeway.errors import InputError

T = TypeVar("T")

#: the seconds one reader call may take before it counts as a hang
HANG_S = 20.0

#: write the counts (``MAKEWAY_FUZZ_COUNTS``) every this many inputs, and at exit
DUMP_EVERY = 500

#: reader name → {"inputs", "accepted", "rejected", "uncaught"}
COUNTS: defaultdict[str, Counter[str]] = defaultdict(Counter)


class ReaderHung(BaseException):
    """A reader call ran past :data:`HANG_S` (a BaseException so that no ``except Exception`` in a
    reader can swallow it)."""


@contextmanager
def _time_limit(seconds: float, name: str) -> Iterator[None]:
    def _raise(signum: int, frame: FrameType | None) -> None:
        raise ReaderHung(f"{name}: no result after {seconds:g} s")

    previous = signal.signal(signal.SIGALRM, _raise)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    # a hang inside C code (a decoder) never returns to Python to see the alarm: then, after twice
    # the time, print every thread's stack and end the process, so the run fails instead of hanging
    faulthandler.dump_traceback_later(2 * seconds, exit=True)
    try:
        yield
    finally:
        faulthandler.cancel_dump_traceback_later()
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def check_reader(
    name: str,
    call: Callable[[], T],
    *,
    inside: Path | None = None,
    allowed: tuple[type[BaseException], ...] = (InputError,),
) -> T | None:
    """Run ``call()`` (one reader on one generated input) under the contract; return its result, or
    ``None`` when it refused the input with an allowed error. Any other exception propagates (and
    fails the test); so does a call that runs past :data:`HANG_S`.

    ``inside``: the folder the generated files live in; an :class:`InputError` must name a path in
    it (the file at fault). Every allowed error's message must be one line.
    """
    COUNTS[name]["inputs"] += 1
    try:
        with _time_limit(HANG_S, name), warnings.catch_warnings():
            # numpy's "invalid value in cast" and the like: a value turned into garbage silently
            warnings.simplefilter("error", RuntimeWarning)
            result = call()
    except allowed as exc:
        message = str(exc)
        one_line = bool(message) and "\n" not in message and "\r" not in message
        # the file itself, one in the folder, or ``FILE:LINE``
        names_it = not isinstance(exc, InputError) or inside is None or str(exc.path).startswith(str(inside))
        COUNTS[name]["rejected" if one_line and names_it else "uncaught"] += 1
        assert one_line, f"not one line: {message!r}"
        assert names_it, f"names {exc.path} (expected a path in {inside})"  # type: ignore[attr-defined]
        return None
    except KeyboardInterrupt:  # the run was stopped (bench_fuzz --max-minutes): not the reader's fault
        COUNTS[name]["inputs"] -= 1
        raise
    except BaseException:
        COUNTS[name]["uncaught"] += 1
        raise
    COUNTS[name]["accepted"] += 1
    if sum(c["inputs"] for c in COUNTS.values()) % DUMP_EVERY == 0:
        _dump_counts()  # so that a run stopped hard still reports what it did
    return result


def _dump_counts() -> None:
    target = os.environ.get("MAKEWAY_FUZZ_COUNTS")
    if target and COUNTS:
        tmp = Path(target + ".partial")
        tmp.write_text(json.dumps({k: dict(v) for k, v in sorted(COUNTS.items())}, indent=1))
        os.replace(tmp, target)


atexit.register(_dump_counts)


# ------------------------------------------------------------------------------------------- budget
PROFILES = {
    # about a minute for every fuzz test together on two busy cores
    "ci": settings(
        max_examples=40,
        deadline=None,
        database=None,
        derandomize=True,
        suppress_health_check=list(HealthCheck),
        print_blob=True,
    ),
    # `make fuzz`: over 100,000 inputs across the readers
    "long": settings(
        max_examples=6000,
        deadline=None,
        database=None,
        suppress_health_check=list(HealthCheck),
        print_blob=True,
    ),
}
PROFILE_ENV = "MAKEWAY_FUZZ_PROFILE"


def budget(weight: float = 1.0) -> settings:
    """Settings for one fuzz test: the loaded profile with ``max_examples`` scaled by ``weight``
    (below 1 for readers that decode video, audio or models, which take longer per input).
    ``MAKEWAY_FUZZ_EXAMPLES`` replaces the profile's ``max_examples`` (a quick deeper look at one
    reader)."""
    base = int(os.environ.get("MAKEWAY_FUZZ_EXAMPLES", 0)) or settings.default.max_examples
    return settings(max_examples=max(5, round(base * weight)))


# ------------------------------------------------------------------------------------- generators
#: single values that break careless parsers
NASTY = [
    "",
    " ",
    "nan",
    "NaN",
    "inf",
    "-inf",
    "Infinity",
    "1e309",
    "-1e309",
    "1e-320",
    "0",
    "-0",
    "-1",
    "2147483648",
    "-9223372036854775809",
    "99999999999999999999999999999",
    "1" * 400,
    "0.5",
    "1e6",
    "abc",
    "0x10",
    "1_000",
    "\x00",
    "é",
    "\ufeff",
    "None",
    "null",
    "true",
    "[]",
    "{}",
    "*",
    '"',
    "'",
    "#",
    "\t",
    "-",
    ":",
    "- -",
    "&a",
    "*a",
    "!!python/object:os.system",
]

_token = st.one_of(
    st.sampled_from(NASTY), st.text(max_size=12), st.integers().map(str), st.floats().map(repr)
)


@st.composite
def mutated_text(draw: st.DrawFn, seed: str, *, sep: str = ",") -> bytes:
    """``seed`` (a text file) with one to four line- and field-level edits, then encoded (UTF-8 mostly;
    sometimes with a BOM, UTF-16 or Latin-1, or with a byte flipped)."""
    lines = seed.splitlines()
    for _ in range(draw(st.integers(1, 4))):
        op = draw(
            st.sampled_from(
                [
                    "field",
                    "drop_field",
                    "add_field",
                    "drop_line",
                    "dup_line",
                    "swap",
                    "insert",
                    "cut",
                    "only_header",
                    "empty_field",
                ]
            )
        )
        if not lines:
            lines = [draw(st.text(max_size=30))]
        i = draw(st.integers(0, len(lines) - 1))
        fields = lines[i].split(sep) if sep in lines[i] else lines[i].split()
        joiner = sep if sep in lines[i] else " "
        if op == "field" and fields:
            fields[draw(st.integers(0, len(fields) - 1))] = draw(_token)
            lines[i] = joiner.join(fields)
        elif op == "empty_field" and fields:
            fields[draw(st.integers(0, len(fields) - 1))] = ""
            lines[i] = joiner.join(fields)
        elif op == "drop_field" and fields:
            del fields[draw(st.integers(0, len(fields) - 1))]
            lines[i] = joiner.join(fields)
        elif op == "add_field":
            fields.insert(draw(st.integers(0, len(fields))), draw(_token))
            lines[i] = joiner.join(fields)
        elif op == "drop_line":
            del lines[i]
        elif op == "dup_line":
            lines.insert(i, lines[i])
        elif op == "swap":
            j = draw(st.integers(0, len(lines) - 1))
            lines[i], lines[j] = lines[j], lines[i]
        elif op == "insert":
            lines.insert(i, draw(st.text(max_size=40)))
        elif op == "cut":
            text = "\n".join(lines)
            lines = text[: draw(st.integers(0, len(text)))].splitlines()
        elif op == "only_header":
            lines = lines[: i + 1]
    text = "\n".join(lines) + draw(st.sampled_from(["\n", "", "\r\n"]))
    enc = draw(st.sampled_from(["utf-8"] * 6 + ["utf-8-sig", "utf-16", "latin-1", "flip"]))
    if enc == "flip":
        return draw(mutated_bytes(text.encode("utf-8"), max_edits=2))
    return text.encode(enc, errors="replace")


_leaf = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(),
    st.integers(-(2**70), 2**70),
    st.floats(),
    st.text(max_size=12),
    st.sampled_from(NASTY),
)
_value = st.recursive(
    _leaf,
    lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=8), c, max_size=4),
    max_leaves=12,
)


def _paths(node: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    out = [prefix]
    if isinstance(node, dict):
        for k, v in node.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(node, list):
        for k, v in enumerate(node):
            out += _paths(v, (*prefix, k))
    return out


@st.composite
def mutated_yaml(draw: st.DrawFn, seed: str) -> bytes:
    """``seed`` (a YAML document) parsed, with one to three edits to its tree (a key or item removed,
    a value replaced by one of another type: NaN, huge integers, nested lists …, a key renamed), dumped
    again; or the text itself mutated line by line."""
    if draw(st.integers(0, 4)) == 0:
        return draw(mutated_text(seed, sep=":"))
    doc = yaml.safe_load(seed)
    for _ in range(draw(st.integers(1, 3))):
        paths = _paths(doc)
        path = draw(st.sampled_from(paths))
        if not path:
            if draw(st.booleans()):
                doc = draw(_value)
            continue
        parent = doc
        for k in path[:-1]:
            parent = parent[k]
        key = path[-1]
        op = draw(st.sampled_from(["replace", "replace", "delete", "rename"]))
        if op == "replace":
            parent[key] = draw(_value)
        elif op == "delete":
            del parent[key]
        elif isinstance(parent, dict):
            parent[draw(st.text(string.ascii_lowercase + "_", max_size=10))] = parent.pop(key)
    return yaml.safe_dump(doc, allow_unicode=True, sort_keys=False).encode("utf-8")


@st.composite
def mutated_bytes(draw: st.DrawFn, seed: bytes, *, max_edits: int = 4) -> bytes:
    """``seed`` (a binary file) with one to ``max_edits`` edits: a byte flipped, a range zeroed or
    replaced by random bytes, bytes inserted or deleted, the file cut short."""
    data = bytearray(seed)
    for _ in range(draw(st.integers(1, max_edits))):
        n = len(data)
        op = draw(st.sampled_from(["flip", "zero", "random", "insert", "delete", "cut", "cut_head"]))
        i = draw(st.integers(0, max(0, n - 1)))
        if op == "flip" and n:
            data[i] ^= 1 << draw(st.integers(0, 7))
        elif op == "zero":
            k = draw(st.integers(1, 4096))
            data[i : i + k] = bytes(len(data[i : i + k]))
        elif op == "random":
            chunk = draw(st.binary(min_size=1, max_size=64))
            data[i : i + len(chunk)] = chunk
        elif op == "insert":
            data[i:i] = draw(st.binary(min_size=1, max_size=256))
        elif op == "delete":
            del data[i : i + draw(st.integers(1, 4096))]
        elif op == "cut":
            del data[i:]
        elif op == "cut_head":
            del data[:i]
    return bytes(data)


def file_contents(seed: bytes | str, kind: str = "text", *, sep: str = ",") -> st.SearchStrategy[bytes]:
    """Generated contents for a file of ``kind`` (``"text"``, ``"yaml"`` or ``"binary"``) whose valid
    example is ``seed``: mostly structure-aware mutations of it, sometimes the seed itself, random
    bytes or an empty file."""
    raw = seed.encode("utf-8") if isinstance(seed, str) else seed
    if kind == "text":
        shaped = mutated_text(raw.decode("utf-8"), sep=sep)
    elif kind == "yaml":
        shaped = mutated_yaml(raw.decode("utf-8"))
    else:
        shaped = mutated_bytes(raw)
    return st.one_of(
        shaped,
        shaped,
        shaped,
        shaped,
        mutated_bytes(raw),
        st.just(raw),
        st.just(b""),
        st.binary(max_size=512),
    )
