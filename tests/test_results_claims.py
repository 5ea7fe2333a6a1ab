"""The figures README.md and benchmarks/results/README.md quote from results files are in those files, and the
results index lists exactly the files whose provenance does not verify. No JAX: text, JSON and arithmetic.

``benchmarks/results/claims.json`` holds one entry per quoted figure: ``doc`` (the README), ``quote`` (the text as
the README writes it), ``file`` (in ``benchmarks/results/``) and either ``find`` (text of that file holding the
figure, or a list of such texts; ``scale`` divides the file's numbers, e.g. 1e6 for a figure quoted in millions) or
``json`` (a dotted path into the ``.json``, optionally ``slice``) with ``stat`` (``mean_std``: mean ± std over the
values, std over the population as the reports compute it; ``values``: the values themselves); ``cited_as``: how the
README names the file where not by its name. Every number of the quote must be a rounding (half up, to the decimals the
quote shows) of a number of its source."""

from __future__ import annotations

import json
import os
import re
import statistics
from decimal import ROUND_HALF_UP, Decimal

import pytest

from benchmarks import provenance_audit

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RESULTS = os.path.join(ROOT, "benchmarks", "results")
DOCS = ("README.md", "benchmarks/results/README.md")
NUMBER = re.compile(r"(?<![\w.])[−-]?\d+(?:[,\u202f ]\d{3})*(?:\.\d+)?(?![\w.])")
SPREAD = re.compile(r"[−-]?\d+(?:[.,]\d+)* ± \d+(?:[.,]\d+)*")


def numbers(text: str) -> list[str]:
    """The numbers in ``text`` as written (``−`` for minus; ``,`` and thin or plain spaces as thousands marks)."""
    return [m.group(0) for m in NUMBER.finditer(text)]


def value(written: str) -> Decimal:
    return Decimal(re.sub(r"[,\u202f ]", "", written.replace("−", "-")))


def rounds_to(exact: Decimal, shown: str) -> bool:
    """Whether ``exact`` rounds (half up) to ``shown`` at the decimals ``shown`` has."""
    places = Decimal(1).scaleb(-len(shown.split(".")[1])) if "." in shown else Decimal(1)
    return exact.quantize(places, rounding=ROUND_HALF_UP) == value(shown)


def _claims() -> list[dict]:
    with open(os.path.join(RESULTS, "claims.json")) as f:
        return json.load(f)["claims"]


def _doc(name: str) -> str:
    with open(os.path.join(ROOT, name)) as f:
        return f.read()


def _source_numbers(claim: dict) -> list[Decimal]:
    path = os.path.join(RESULTS, claim["file"])
    if "json" in claim:
        with open(path) as f:
            data = json.load(f)
        for key in claim["json"].split("."):
            data = data[int(key)] if isinstance(data, list) else data[key]
        values = [float(v) for v in data[slice(*claim.get("slice", (None,)))]]
        assert claim["stat"] in ("mean_std", "values"), claim
        if claim["stat"] == "values":
            return [Decimal(repr(v)) for v in values]
        return [Decimal(repr(statistics.fmean(values))), Decimal(repr(statistics.pstdev(values)))]
    with open(path) as f:
        text = f.read()
    finds = [claim["find"]] if isinstance(claim["find"], str) else claim["find"]
    for find in finds:
        assert find in text, f"{claim['file']} does not hold {find!r}"
    scale = Decimal(str(claim.get("scale", 1)))
    return [value(n) / scale for find in finds for n in numbers(find)]


@pytest.mark.parametrize("claim", _claims(), ids=lambda c: f"{c['quote']} <- {c['file']}")
def test_each_quoted_figure_is_in_its_file(claim):
    assert claim["doc"] in DOCS and claim["quote"] in _doc(claim["doc"]), f"{claim['doc']} no longer says it"
    cited = claim.get("cited_as", claim["file"].rsplit(".", 1)[0])
    assert cited in _doc(claim["doc"]), f"{claim['doc']} does not name {cited}"
    source = _source_numbers(claim)
    missing = [n for n in numbers(claim["quote"]) if not any(rounds_to(v, n) for v in source)]
    where = claim.get("find", claim.get("json"))
    assert missing == [], f"{claim['quote']!r}: {missing} not in {claim['file']} ({where})"


def test_every_spread_the_readmes_quote_is_claimed():
    """Each ``mean ± std`` either README writes is in a claim's quote (so a new one needs its file named)."""
    quoted = {c["doc"]: [] for c in _claims()}
    for c in _claims():
        quoted[c["doc"]].append(c["quote"])
    unclaimed = [(doc, m) for doc in DOCS for m in SPREAD.findall(_doc(doc))
                 if not any(m in q for q in quoted.get(doc, []))]  # fmt: skip
    assert unclaimed == []


def test_the_checks_fail_for_the_right_reason():
    """A quote rounded the wrong way, or read from another row, is caught."""
    assert rounds_to(Decimal("1058.6"), "1059") and not rounds_to(Decimal("1058.6"), "1058")
    assert rounds_to(Decimal("1882.5"), "1883") and not rounds_to(Decimal("20.0"), "19.7")
    assert numbers("−14.5 ± 0.3 (8 seeds), 2,350,470 steps/s, 200 192") == ["−14.5", "0.3", "8", "2,350,470",
                                                                             "200 192"]  # fmt: skip
    claim = {"doc": DOCS[1], "quote": "19.7", "file": "gpu-nvidia_h100_80gb_hbm3-racing-bcloss3-td3.md",
             "find": "| td3 | train | 20.0 ± 0.0 |"}  # fmt: skip
    assert not any(rounds_to(v, "19.7") for v in _source_numbers(claim))


def test_the_unverified_files_listed_are_those_the_audit_finds():
    """benchmarks/results/README.md's "Unverified files" table names exactly the files whose provenance does not
    verify (:func:`benchmarks.provenance.audit`, without the history check, which needs the whole git history)."""
    text = _doc(DOCS[1])
    section = text.split("## Unverified files", 1)[1].split("\n## ", 1)[0]
    listed = {os.path.splitext(m)[0] for m in re.findall(r"^\| `([^`]+)` \|", section, re.M)}
    assert listed == set(provenance_audit.audit(RESULTS))
