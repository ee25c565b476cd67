#!/usr/bin/env python3
"""Writes the Parquet files the tests read, as other tools write them (pyarrow 26, the
engine pandas and many loggers use): interchange recordings in `tests/parquet/` and broken
ones in `tests/bad-input/`. Values are exact binary products (k * 1e-4 and the like) so a
test can recompute every one. Run once; the files are committed.

    python3 -m venv /tmp/venv && /tmp/venv/bin/pip install pyarrow pandas
    /tmp/venv/bin/python tests/parquet/make.py
"""
import os

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

HERE = os.path.dirname(os.path.abspath(__file__))
BAD = os.path.join(os.path.dirname(HERE), "bad-input")
N = 300
CHANNELS = ["gx_rad_s", "gy_rad_s", "gz_rad_s", "ax_m_s2", "ay_m_s2", "az_m_s2"]


def frame():
    """t_s = k * 0.01; channel c at row k = ((k * (c + 3)) % 17 - 8) * 1e-4 (c = 0..5)."""
    k = np.arange(N)
    df = pd.DataFrame({"t_s": k * 0.01})
    for c, name in enumerate(CHANNELS):
        df[name] = ((k * (c + 3)) % 17 - 8) * 1e-4
    return df


def with_rate(table, rate):
    return table.replace_schema_metadata({**(table.schema.metadata or {}),
                                          b"sample_rate_hz": str(rate).encode()})


def main():
    df = frame()
    df["note"] = "bench"
    # pandas' own writer: snappy, dictionary pages, nullable columns, the pandas metadata.
    table = with_rate(pa.Table.from_pandas(df, preserve_index=False), 100)
    pq.write_table(table, os.path.join(HERE, "pandas-snappy.parquet"))
    # Small row groups and pages, zstd, a float32 gyro and an int64 counter among them.
    df2 = frame()
    df2["gx_rad_s"] = df2["gx_rad_s"].astype("float32")
    df2["count"] = np.arange(N, dtype=np.int64)
    pq.write_table(pa.Table.from_pandas(df2, preserve_index=False),
                   os.path.join(HERE, "zstd-small-groups.parquet"), compression="zstd",
                   row_group_size=64, data_page_size=256, use_dictionary=False)

    def bad(name, table, **kw):
        pq.write_table(table, os.path.join(BAD, name), **kw)

    base = pa.Table.from_pandas(frame(), preserve_index=False)
    gz = base.column("gz_rad_s").to_pylist()
    gz[57] = None
    bad("parquet-null.parquet", base.set_column(3, "gz_rad_s", pa.array(gz, pa.float64())))
    gy = base.column("gy_rad_s").to_pylist()
    gy[120] = float("nan")
    bad("parquet-nan.parquet",
        base.set_column(2, "gy_rad_s", pa.array(gy, pa.float64(), from_pandas=False)))
    text = [repr(v) for v in base.column("gx_rad_s").to_pylist()]
    bad("parquet-text-column.parquet", base.set_column(1, "gx_rad_s", pa.array(text)))
    t = base.column("t_s").to_pylist()
    t[200] = t[199]
    bad("parquet-time-backwards.parquet", base.set_column(0, "t_s", pa.array(t)))
    bad("parquet-rate-wrong.parquet", with_rate(base, 50))
    stamps = pa.array((np.arange(N) * 10_000).astype("datetime64[us]"))
    bad("parquet-timestamp-time.parquet", base.set_column(0, "t_s", stamps))
    whole = os.path.join(BAD, "parquet-cut.parquet")
    bad("parquet-cut.parquet", base)
    data = open(whole, "rb").read()
    open(whole, "wb").write(data[: len(data) * 3 // 5])


if __name__ == "__main__":
    main()
