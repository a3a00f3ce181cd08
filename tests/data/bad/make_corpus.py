"""Writes the files of this directory: realistic mistakes made from the first 40 fixes of the real
car trace (tests/data/around-visnjan-with-car.gpx, CC BY 4.0, see its LICENSE file).

Run from the repository root: ``python tests/data/bad/make_corpus.py``.  The expected outcome of
``mptrack track`` on each file is in ``tests/test_bad_inputs.py``.
"""

from pathlib import Path

import numpy as np
import pandas as pd

from mptrack.io import read_table

HERE = Path(__file__).parent
N = 40


def fixes() -> pd.DataFrame:
    rows = read_table(HERE.parent / "around-visnjan-with-car.gpx").iloc[:N]
    return pd.DataFrame({"track_id": "car", "time": rows["time"].dt.strftime("%Y-%m-%dT%H:%M:%SZ"),
                         "lat": rows["lat"].round(7), "lon": rows["lon"].round(7),
                         "elevation_m": rows["elevation_m"]})


def write(name: str, df: pd.DataFrame, **kw) -> None:
    df.to_csv(HERE / name, index=False, **kw)


def main() -> None:
    f = fixes()
    t = pd.to_datetime(f["time"])
    secs = (t - pd.Timestamp("1970-01-01", tz="UTC")) // pd.Timedelta("1s")
    write("good.csv", f)
    (HERE / "bom.csv").write_bytes(b"\xef\xbb\xbf" + f.to_csv(index=False).encode())
    write("crlf.csv", f, lineterminator="\r\n")
    write("semicolon-decimal-comma.csv", f, sep=";", decimal=",")
    write("quoted-numbers.csv", f, quoting=1)  # csv.QUOTE_ALL
    local = f.assign(time=(t.dt.tz_convert("Europe/Zagreb")).map(lambda x: x.isoformat()))
    write("tz-offset.csv", local)
    # swapped within the valid ranges (13.7 N 45.3 E); only the UTC offset +01:00 tells
    write("lat-lon-swapped-tz.csv", local.assign(lat=f["lon"], lon=f["lat"]))
    mixed = t.map(lambda x: x.isoformat()).where(np.arange(N) % 2 == 0,
                                                  t.dt.tz_convert("Europe/Zagreb").map(lambda x: x.isoformat()))
    write("mixed-tz.csv", f.assign(time=mixed))
    two = pd.concat([f.iloc[:20], f.iloc[20:].assign(track_id="bus")])
    write("two-tracks-interleaved.csv", two.iloc[np.argsort(np.r_[np.arange(20) * 2, np.arange(20) * 2 + 1],
                                                           kind="stable")])
    write("shuffled.csv", f.sample(frac=1.0, random_state=3))
    gap = f.copy()
    gap.loc[20:, "time"] = (t[20:] + pd.Timedelta(days=3)).dt.strftime("%Y-%m-%dT%H:%M:%SZ")
    write("three-day-gap.csv", gap)
    write("dd-mm-yyyy.csv", f.assign(time=t.dt.strftime("%d/%m/%Y %H:%M:%S")))
    write("degrees-e7.csv", f.assign(lat=(f["lat"] * 1e7).round().astype("int64"),
                                     lon=(f["lon"] * 1e7).round().astype("int64")))
    write("degrees-e6.csv", f.assign(lat=(f["lat"] * 1e6).round().astype("int64"),
                                     lon=(f["lon"] * 1e6).round().astype("int64")))
    write("radians.csv", f.assign(lat=np.radians(f["lat"]), lon=np.radians(f["lon"])))
    # a trace at 113.7 E written with the columns swapped (the car trace moved 100 degrees east)
    write("lat-lon-swapped.csv", f.assign(lat=f["lon"] + 100.0, lon=f["lat"]))
    write("epoch-seconds.csv", f.assign(time=secs))
    write("iso-without-zone.csv", f.assign(time=f["time"].str.removesuffix("Z")))
    write("epoch-milliseconds.csv", f.assign(time=secs * 1000))
    write("epoch-ambiguous.csv", f.assign(time=secs * 10))  # ~1.6e10: seconds in 2476 or ms in 1970
    (HERE / "empty.csv").write_bytes(b"")
    write("header-only.csv", f.iloc[:0])
    write("odd-column-names.csv", f.rename(columns={"track_id": "Device", "time": "Timestamp", "lat": "Latitude",
                                                     "lon": "Lng"}))
    write("unknown-column-names.csv", f.rename(columns={"lat": "Breite", "lon": "Laenge"}))
    write("row-id-column.csv", f.rename(columns={"track_id": "id"}).assign(id=np.arange(1, N + 1)))
    write("two-latitudes.csv", f.rename(columns={"lat": "LAT"}).assign(Latitude=f["lat"]))
    dup = pd.concat([f.iloc[:10], f.iloc[5:8], f.iloc[10:]]).sort_values("time", kind="stable")
    write("duplicate-rows.csv", dup)
    same = pd.concat([f.iloc[:10], f.iloc[9:10].assign(lat=f["lat"].iloc[9] + 0.001), f.iloc[10:]])
    write("same-time-other-position.csv", same)
    (HERE / "garbage.csv").write_bytes(bytes(range(256)) * 4)
    write("missing-latitude.csv", f.assign(lat=f["lat"].where(np.arange(N) != 12)))
    write("no-time-column.csv", f.drop(columns="time"))
    (HERE / "spreadsheet.xlsx").write_bytes(b"PK\x03\x04 not really a spreadsheet")
    gpx = (HERE.parent / "around-visnjan-with-car.gpx").read_text()
    first = gpx.index("<time>", gpx.index("<trkpt"))
    for _ in range(5):  # drop the <time> of the sixth point
        first = gpx.index("<time>", first + 1)
    end = gpx.index("</time>", first) + len("</time>")
    (HERE / "untimed-point.gpx").write_text(gpx[:first] + gpx[end:])


if __name__ == "__main__":
    main()
