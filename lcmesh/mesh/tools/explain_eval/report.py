"""Aggregate explain-eval items and write the markdown report."""

from __future__ import annotations

from collections import Counter

_SCORES = ("numeric_grounding", "coverage", "direction_consistency")


def aggregate(items: list[dict]) -> dict:
    """Means over valid items (macro), pooled number and direction counts (micro), flag counts."""
    invalid = [it for it in items if any(f["kind"] == "invalid_record" for f in it["flags"])]
    unread = [it for it in items if any(f["kind"] == "not_read" for f in it["flags"])]
    valid = [it for it in items if it not in invalid and it not in unread]
    n = len(valid)
    agg: dict = {"n_items": len(items), "n_valid": n, "n_invalid": len(invalid), "n_not_read": len(unread)}
    for key in _SCORES:
        agg[key] = sum(it[key] for it in valid) / n if n else 0.0
        agg[f"{key}_min"] = min((it[key] for it in valid), default=0.0)
    numbers = [it.get("numbers", {}) for it in valid]
    checked = sum(x.get("checked", 0) for x in numbers)
    agg["numbers_checked"] = checked
    agg["numbers_grounded"] = sum(x.get("grounded", 0) for x in numbers)
    agg["numbers_derived"] = sum(x.get("derived", 0) for x in numbers)
    agg["numeric_grounding_pooled"] = agg["numbers_grounded"] / checked if checked else 1.0
    directions = [it.get("directions", {}) for it in valid]
    agg["direction_claims_checked"] = sum(d.get("checked", 0) for d in directions)
    agg["direction_claims_consistent"] = sum(d.get("consistent", 0) for d in directions)
    counts = Counter(f["kind"] for it in items for f in it["flags"])
    agg["claims_checked"] = sum(len(it.get("claims", [])) for it in valid)
    agg["claims_failed"] = sum(c["verdict"] == "fails" for it in valid for c in it.get("claims", []))
    agg["flag_counts"] = dict(sorted(counts.items()))
    agg["items_without_flags"] = sum(1 for it in valid if not it["flags"])
    return agg


def render_markdown(result: dict, title: str = "Explanation evaluation") -> str:
    """A markdown report: the aggregate, then one row per item and the flags in full."""
    agg = result["aggregate"]
    lines = [
        f"# {title}",
        "",
        f"{agg['n_items']} explanations ({agg['n_invalid']} invalid lines); "
        f"{agg['items_without_flags']} without flags.",
        "",
        "| score | mean | min |",
        "|---|---|---|",
    ]
    lines += [f"| {k} | {agg[k]:.3f} | {agg[k + '_min']:.3f} |" for k in _SCORES]
    lines += [
        "",
        f"Numbers: {agg['numbers_grounded']} of {agg['numbers_checked']} grounded "
        f"({agg['numbers_derived']} as stated differences or sums). Direction claims: "
        f"{agg['direction_claims_consistent']} of {agg['direction_claims_checked']} consistent.",
        "",
        "| flag | count |",
        "|---|---|",
    ]
    lines += [f"| {k} | {v} |" for k, v in agg["flag_counts"].items()] or ["| (none) | 0 |"]
    lines += ["", "## Items", "", "| id | grounding | coverage | direction | flags |", "|---|---|---|---|---|"]
    for it in result["items"]:
        kinds = ", ".join(sorted({f["kind"] for f in it["flags"]})) or "-"
        lines.append(f"| {it['id']} | {it['numeric_grounding']:.2f} | {it['coverage']:.2f} | "
                     f"{it['direction_consistency']:.2f} | {kinds} |")  # fmt: skip
    flagged = [it for it in result["items"] if it["flags"]]
    if flagged:
        lines += ["", "## Flags", ""]
        for it in flagged:
            for f in it["flags"]:
                lines.append(f"- `{it['id']}` **{f['kind']}**: {f['detail'].replace('|', '/')}")
    return "\n".join(lines) + "\n"
