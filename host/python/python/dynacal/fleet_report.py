"""The fleet screening's ``report.html``: one self-contained page (figures inlined as PNG).

It shows the lot's distribution of every compared parameter, each unit's z-score against the
lot with the rule's threshold, the units out of family with the parameter that named them, and
the units that failed with their error. Built from the table ``dynacal.fleet`` writes, so the
page and ``fleet.parquet`` cannot disagree.
"""

from __future__ import annotations

import base64
import html
import io
import math
from typing import Any, Dict, List, Sequence, Tuple

_STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 72em; color: #222; }
table { border-collapse: collapse; margin: 1em 0; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; text-align: left; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
img { max-width: 100%; }
.flag { color: #b00; }
"""


def _tested_groups(table) -> List[Tuple[str, str]]:
    """(channel, parameter column) pairs the rule compared, in channel order."""
    from . import CHANNELS

    columns = [c[:-2] for c in table.columns if c.endswith("_z")]
    channels = sorted(set(table["channel"]), key=lambda c: (CHANNELS.index(c) if c in CHANNELS else 99, c))
    groups = []
    for channel in channels:
        rows = table[table["channel"] == channel]
        for col in columns:
            if rows[col + "_z"].notna().any():
                groups.append((channel, col))
    return groups


def _group_by_column(summary) -> Dict[Tuple[str, str], Any]:
    """The rule's groups by (channel, Parquet column)."""
    from .fleet import parameter_column

    return {(ch, parameter_column(process, name)): g
            for (ch, process, name), g in summary.groups.items()}


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    return base64.b64encode(buf.getvalue()).decode("ascii")


_CHANNEL_COLOURS = {"gx": "#4a7ab5", "gy": "#5aa469", "gz": "#c08a2e",
                    "ax": "#7b5ea7", "ay": "#3fa7a3", "az": "#a0522d"}


def _figure(table, groups: Sequence[Tuple[str, str]], summary, kind: str) -> str:
    """One panel per compared parameter, the channels in colour. ``kind`` "distribution":
    histograms of log10(value), the units out of family marked in red; "z": every unit's
    z-score against the lot with each channel's threshold +-k."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    columns = list(dict.fromkeys(col for _, col in groups))
    spread = _group_by_column(summary)
    n_cols = min(2, len(columns))
    n_rows = (len(columns) + n_cols - 1) // n_cols
    fig, axes = plt.subplots(n_rows, n_cols, squeeze=False, figsize=(6.0 * n_cols, 2.8 * n_rows))
    for ax in axes.flat[len(columns):]:
        ax.set_axis_off()
    for ax, col in zip(axes.flat, columns):
        for channel in [ch for ch, c in groups if c == col]:
            rows = table[table["channel"] == channel]
            colour = _CHANNEL_COLOURS.get(channel, "#555")
            flagged = rows[col + "_p_value"].to_numpy(dtype=float) < summary.p_threshold
            files = rows["file"].to_numpy()
            if kind == "distribution":
                values = np.abs(rows[col].to_numpy(dtype=float))
                logs = np.log10(values[np.isfinite(values) & (values > 0)])
                ax.hist(logs, bins=30, histtype="step", color=colour, label=channel)
                for v, f in zip(values[flagged], files[flagged]):
                    ax.axvline(math.log10(v), color="#b00", lw=1.2)
                    ax.annotate(f"{f} ({channel})", (math.log10(v), 0), rotation=90, fontsize=6,
                                color="#b00", xytext=(2, 2), textcoords="offset points",
                                va="bottom")
                ax.set_xlabel(f"log10 {col}", fontsize=7)
            else:
                z = rows[col + "_z"].to_numpy(dtype=float)
                index = np.arange(z.size)
                ax.scatter(index[~flagged], z[~flagged], s=3, color=colour, label=channel)
                ax.scatter(index[flagged], z[flagged], s=14, color="#b00")
                for x, y, f in zip(index[flagged], z[flagged], files[flagged]):
                    ax.annotate(f"{f} ({channel})", (x, y), fontsize=6, color="#b00",
                                xytext=(3, 0), textcoords="offset points")
                k = spread[(channel, col)].k
                for level in (-k, k):
                    ax.axhline(level, color=colour, ls="--", lw=0.6)
                ax.set_xlabel("unit (file order)", fontsize=7)
                ax.set_ylabel(f"z of {col}", fontsize=7)
        ax.set_title(col, fontsize=8)
        ax.tick_params(labelsize=6)
        ax.legend(fontsize=6, loc="best")
    fig.tight_layout()
    try:
        return _png(fig)
    finally:
        plt.close(fig)


def _flag_rows(table, summary) -> List[Dict[str, Any]]:
    """One line per flagged parameter: the unit, its value, the lot's median, z and p."""
    out = []
    spread = _group_by_column(summary)
    for _, row in table[table["out_of_family"]].iterrows():
        for col in str(row["flagged_by"]).split(","):
            group = spread[(row["channel"], col)]
            out.append({
                "file": row["file"], "sensor": row["sensor"], "channel": row["channel"],
                "parameter": col, "value": row[col], "lot_median": math.exp(group.mu),
                "z": row[col + "_z"], "p_value": row[col + "_p_value"],
                "p_value_lot": min(1.0, row[col + "_p_value"] * summary.n_tests),
            })
    return out


def _table_html(rows: Sequence[Dict[str, Any]], columns: Sequence[str], css: str = "") -> str:
    def cell(v: Any) -> str:
        if isinstance(v, float):
            return f'<td class="num">{v:.4g}</td>'
        return f"<td>{html.escape(str(v))}</td>"

    head = "".join(f"<th>{html.escape(c)}</th>" for c in columns)
    body = "".join(f'<tr class="{css}">' + "".join(cell(r[c]) for c in columns) + "</tr>" for r in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def render(table, summary, failed: Sequence[Dict[str, str]], model: str, engine: str,
           n_units: int) -> str:
    """The whole page."""
    k_low, k_high = summary.k_range()
    flags = _flag_rows(table, summary)
    groups = _tested_groups(table) if len(table) else []
    units_flagged = sorted({f["file"] for f in flags})
    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'><title>dynacal fleet screening</title>",
        f"<style>{_STYLE}</style></head><body>",
        "<h1>Fleet screening</h1>",
        f"<p>{n_units} units, {len(table)} channels fitted with the model "
        f"<code>{html.escape(model)}</code> on {html.escape(engine)}; "
        f"{len(failed)} failed; <span class='flag'>{len(units_flagged)} out of family</span>.</p>",
        "<h2>The rule</h2>",
        "<p>Per channel and parameter, on the log scale, the lot's centre is the median and its "
        "spread 1.4826 MAD; a unit's z-score divides its distance to the centre by the lot's own "
        "unit-to-unit spread combined with the unit's estimation error (from its fit's 95% "
        "interval), and is read as a Student t of 0.37 (n - 1) degrees of freedom. A parameter "
        f"is out of family when its two-sided p-value is under {summary.p_threshold:.3g} = "
        f"{summary.alpha:g} / {summary.n_tests} tests (|z| &gt; k, k = {k_low:.2f} to "
        f"{k_high:.2f} over the groups), so that a lot with no unit out of family raises a flag "
        f"with probability at most {summary.alpha:g}. Parameters a unit's data cannot pin down "
        "(no finite interval) are not judged.</p>",
        "<h2 id='out-of-family'>Units out of family</h2>",
    ]
    if flags:
        parts.append(_table_html(flags, ["file", "sensor", "channel", "parameter", "value",
                                         "lot_median", "z", "p_value", "p_value_lot"], "flag"))
    else:
        parts.append("<p>None.</p>")
    parts.append("<h2 id='failed'>Units that failed</h2>")
    parts.append(_table_html(failed, ["file", "error"]) if failed else "<p>None.</p>")
    if groups:
        parts += [
            "<h2>Distributions across the lot</h2>",
            "<p>Histograms of log10 of each compared parameter, the channels in colour; red lines "
            "mark the units out of family.</p>",
            f"<img alt='distributions' src='data:image/png;base64,{_figure(table, groups, summary, 'distribution')}'>",
            "<h2>Each unit against the lot</h2>",
            "<p>z-score of every unit (in file order) with the group's threshold &plusmn;k.</p>",
            f"<img alt='z-scores' src='data:image/png;base64,{_figure(table, groups, summary, 'z')}'>",
        ]
    parts.append("</body></html>")
    return "\n".join(parts)
