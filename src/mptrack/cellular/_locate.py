"""A position from one scan of cells: the posterior of the phone's position given the levels and timing
advances it reports and what the cell table knows, evaluated on a grid.

For one request (the cells a phone hears at one time) with the cells' sites, intercepts and slopes
(:mod:`._signal_model`), each site s (cells within 1 m of each other are one site: co-sited sector cells
are one range measurement, not m independent ones) ranges by the first of its cells listed with a level
(a phone lists its serving cell first):

    s_s = A_s - n_s log10(d_s / 1 km) + g_s + e_s,   e_s ~ N(0, SITE_DB^2 + CELL_DB^2 + the intercept's errors)

the intercept's errors being its own and its environment's (the prior's, shrunk by the fits of the cell's
area), and g_s the serving sector's loss off its axis: A_s is the level on a sector's axis (the prior's
and the table fits' alike), while the sector that serves a phone faces it within 60 degrees (a site's three
sectors are 120 degrees apart), so g_s = -12 (theta / 65 degrees)^2 dB (the horizontal pattern of
3GPP TR 36.814, a 65-degree beam) with theta uniform over 0..60 degrees: 0 to -10.2 dB, -3.4 on average.
Taken as part of e_s, this loss made every range ~25 % too long (the position pulled away from the
strongest sites).  The likelihood of the level, a Gaussian averaged over theta, is tabulated in units of
the site's sigma (LOSS_STEP; bilinear interpolation is within 3e-3 of the formula).

A site whose sectors' azimuths the table gives has a bearing prior: a wrapped normal of
SECTOR_SD_DEG around its first sector's azimuth, mixed with a flat tail of weight SECTOR_OUTLIER
(reflections serve a sector from elsewhere), tabulated at BEARING_STEPS steps over 0..180 degrees
(linear interpolation, within 1e-7 of the formula).  The distances have a scale-free (log-uniform) prior.

A timing advance TA of a GSM or LTE cell is a range ring: d ~ N((TA + 1/2) step, step^2 / 12 +
step^2 + TA_FLOOR_M^2) (the step's quantisation, one step of timing error, the site's position),
mixed with a flat tail of weight TA_OUTLIER: a stale or misreported value then moves the position
less than a level-and-ring contradiction would.

The prior is flat over the region every heard site reaches (each site's distance bound: the levels'
2.5-sigma range, a ring's outer edge, the table's range); the posterior is evaluated on a grid over
it, then on finer grids over the part that holds its mass.  The position is the posterior mean, and
``accuracy`` the radius of the circle around it holding ``level`` of the posterior mass (68 % by
default, Google's and Android's convention; Ichnaea states 95 %), widened by the site positions'
uncertainty (30 m for exact positions, 20 % of the range for averaged ones).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .._core import jit_cache  # noqa: F401 - compiled kernels cache in the user's cache directory
from .._core.validation import as_array, as_real, check_int
from ..errors import ParameterError, ShapeError
from ._signal_model import RADIOS

__all__ = ["locate_cells", "check_cells", "CELL_FIELDS", "FIX_FIELDS", "CONFIDENCE"]

#: The columns of the table :func:`locate_cells` reads, one row per cell heard (see its doc).
CELL_FIELDS = ("lat", "lon", "radio", "intercept_dbm", "slope_db", "fit_offset_db", "area_fits",
               "area_offset_db", "range_m", "changeable", "azimuth_deg", "rss_dbm", "ta")
#: The columns of the result of :func:`locate_cells`, one row per request.
FIX_FIELDS = ("lat", "lon", "accuracy_m", "var_e", "cov_en", "var_n", "sites")
#: The confidence level of ``accuracy`` by default: the radius holds the true position with this probability.
CONFIDENCE = 0.68

SITE_DB = 5.0          # shadowing of the path to one site, shared by its sector cells
CELL_DB = 3.0          # each cell's own share (antenna, band, fading)
PRIOR_COMMON_DB = 11.0  # the prior intercept's error shared by an area's cells (environment class, band)
PRIOR_CELL_DB = 4.0    # ... and each cell's own (power, antenna, tilt)
FIT_DB = 6.0           # the error of an intercept fitted from averageSignal and range
FIT_BIAS_DB = 4.0      # ... and of an area's mean fit (where the crowd observed the cells)
MISSING_DB = 12.0      # a cell heard without a level: the radio's typical level, this much less certain
SECTOR_SD_DEG = 60.0   # a sector serves within about +-60 degrees of its azimuth
SECTOR_BEAM_DEG = 65.0  # a sector antenna's 3-dB beamwidth (3GPP TR 36.814: loss 12 (theta / beam)^2 dB)
SECTOR_LOSS_DB = 12.0 * (60.0 / SECTOR_BEAM_DEG) ** 2  # ... at 60 degrees: the serving sector's largest loss
SECTOR_OUTLIER = 0.4   # ... except where reflections serve it from elsewhere
TA_OUTLIER = 0.4       # weight of the flat tail of a timing-advance ring
TA_FLOOR_M = 30.0      # the site's position error in a ring (m)
TA_LONG = 1.0          # a ring's far side is softer by this fraction of its radius (excess delay, stale values)
EXACT_SITE_M = 30.0    # site position uncertainty of an exact table position (changeable = 0)
AVERAGED_SITE = 0.2    # ... of an averaged one, as a fraction of its range (at least 100 m)
MIN_DISTANCE_M = 10.0  # the path-loss models end here
MAX_REACH_M = 40_000.0
MIN_REACH_M = 200.0
GRID = 16              # grid points per axis of each pass
PASSES = 3
EARTH_M = 6_371_008.8

_LN_KM = math.log(1000.0)
_INV_LN10 = 1.0 / math.log(10.0)
_RADIO_TA = np.array([r.ta_step_m for r in RADIOS])
_RADIO_TYPICAL = np.array([r.typical_dbm for r in RADIOS])
_JIT = dict(cache=True, nogil=True, error_model="numpy")


@nb.njit(**_JIT)
def _intercept(a0, area_n, area_off):
    """(A, its own error sd, its environment error sd) of one cell: the prior, moved by the mean fit of the
    cell's area, weighted by the fits' noise (shrinking with their number) and their bias (which does not)."""
    if area_n >= 1 and area_off == area_off:
        var_fit = FIT_BIAS_DB ** 2 + (FIT_DB ** 2 + PRIOR_CELL_DB ** 2) / area_n
        w = PRIOR_COMMON_DB ** 2 / (PRIOR_COMMON_DB ** 2 + var_fit)
        return a0 + w * area_off, PRIOR_CELL_DB, math.sqrt(w * var_fit)
    return a0, PRIOR_CELL_DB, PRIOR_COMMON_DB


def _bearing_log(delta_deg: np.ndarray) -> np.ndarray:
    """log of the sector's bearing prior at ``delta_deg`` (0..180) from its azimuth: a wrapped normal around
    the azimuth mixed with a flat tail."""
    d = delta_deg / SECTOR_SD_DEG
    return np.log((1.0 - SECTOR_OUTLIER) * np.exp(-0.5 * d * d) / (SECTOR_SD_DEG * math.sqrt(2.0 * math.pi))
                  + SECTOR_OUTLIER / 360.0)


#: _bearing_log tabulated at BEARING_STEPS steps over 0..180 degrees (linear interpolation between them is
#: within 1e-7 of it: its second derivative is at most 1 / SECTOR_SD_DEG^2 a square degree)
BEARING_STEPS = 4096
_BEARING_TABLE = _bearing_log(np.linspace(0.0, 180.0, BEARING_STEPS + 1))
_STEPS_PER_DEG = BEARING_STEPS / 180.0


@nb.njit(**_JIT)
def _bearing_prior(sin_az, cos_az, dx, dy):
    """log of the bearing prior (_bearing_log) of a sector whose azimuth has sine and cosine ``sin_az``,
    ``cos_az``, at the offset (dx, dy) (east, north) from its site."""
    u = math.degrees(math.atan2(abs(dx * cos_az - dy * sin_az), dx * sin_az + dy * cos_az)) * _STEPS_PER_DEG
    i = min(int(u), BEARING_STEPS - 1)
    return _BEARING_TABLE[i] + (u - i) * (_BEARING_TABLE[i + 1] - _BEARING_TABLE[i])


#: The level's log-likelihood tabulated (see _level_log): rows over kappa = SECTOR_LOSS_DB / sigma from 0 to its
#: largest (sigma is at least SITE_DB, CELL_DB and PRIOR_CELL_DB together), columns over z = residual / sigma
#: from -(kappa's largest + LOSS_TAIL) to LOSS_TAIL, both at LOSS_STEP
LOSS_STEP = 0.05
LOSS_TAIL = 8.0
_KAPPA_MAX = SECTOR_LOSS_DB / math.sqrt(SITE_DB ** 2 + CELL_DB ** 2 + PRIOR_CELL_DB ** 2)
_KAPPA_N = int(math.ceil(_KAPPA_MAX / LOSS_STEP)) + 1
_Z_LO = -(_KAPPA_N * LOSS_STEP + LOSS_TAIL)
_Z_N = int(round((LOSS_TAIL - _Z_LO) / LOSS_STEP))


def _level_log(z: np.ndarray, kappa: np.ndarray, points: int = 256) -> np.ndarray:
    """log of the mean over theta (uniform over 0..60 degrees) of exp(-(z + kappa (theta / 60)^2)^2 / 2): the
    log-likelihood of a level's standardised residual z = (s - A + n log10 d) / sigma when the serving sector
    loses kappa sigma (theta / 60)^2 off its axis (midpoint rule over ``points`` angles)."""
    u2 = ((np.arange(points) + 0.5) / points) ** 2
    e = -0.5 * (np.asarray(z)[..., None] + np.asarray(kappa)[..., None] * u2) ** 2
    top = e.max(axis=-1)
    return top + np.log(np.exp(e - top[..., None]).mean(axis=-1))


_LEVEL_TABLE = _level_log(_Z_LO + LOSS_STEP * np.arange(_Z_N + 1)[None, :],
                          LOSS_STEP * np.arange(_KAPPA_N + 1)[:, None])


@nb.njit(**_JIT)
def _level_row(kappa):
    """The row of _LEVEL_TABLE at ``kappa`` (linear between its rows): a site's likelihood over z."""
    k = kappa / LOSS_STEP
    j = min(int(k), _KAPPA_N - 1)
    f = k - j
    return _LEVEL_TABLE[j] + f * (_LEVEL_TABLE[j + 1] - _LEVEL_TABLE[j])


@nb.njit(**_JIT)
def _level_loglik(r, inv_sd, kappa, row):
    """_level_log at z = r * inv_sd from the site's ``row`` (_level_row(kappa)), linear between its points;
    beyond them, the Gaussian of the nearest loss continues the edge value."""
    z = r * inv_sd
    shift = 0.0
    if z > LOSS_TAIL:
        shift = -0.5 * (z * z - LOSS_TAIL * LOSS_TAIL)
        z = LOSS_TAIL
    elif z < _Z_LO:
        shift = -0.5 * ((z + kappa) ** 2 - (_Z_LO + kappa) ** 2)
        z = _Z_LO
    x = (z - _Z_LO) / LOSS_STEP
    i = min(int(x), _Z_N - 1)
    return row[i] + (x - i) * (row[i + 1] - row[i]) + shift


@nb.njit(**_JIT)
def _loglik(px, py, sx, sy, a, n, rss, inv_sd, kappa, rows, site_az, sin_az, cos_az, ta_site, ta_mu, ta_sd, ta_tail,
            ns, logd):
    """The log-posterior (up to a constant) of position (px, py) (scratch array logd, per site)."""
    ll = 0.0
    for s in range(ns):
        dx, dy = px - sx[s], py - sy[s]
        ln_d = 0.5 * math.log(max(dx * dx + dy * dy, MIN_DISTANCE_M * MIN_DISTANCE_M))
        logd[s] = (ln_d - _LN_KM) * _INV_LN10
        ll -= 2.0 * ln_d / ns  # the scale-free prior on the distances (log-uniform)
        if site_az[s] == site_az[s]:
            ll += _bearing_prior(sin_az[s], cos_az[s], dx, dy)
        ll += _level_loglik(rss[s] - a[s] + n[s] * logd[s], inv_sd[s], kappa[s], rows[s])
    for s in range(ns):
        if ta_site[s]:
            d = 10.0 ** logd[s] * 1000.0
            lo, up = ta_sd[s], ta_sd[s] + TA_LONG * ta_mu[s]
            z = (d - ta_mu[s]) / (lo if d < ta_mu[s] else up)
            ll += math.log((1.0 - TA_OUTLIER) * math.exp(-0.5 * z * z) / (0.5 * (lo + up) * 2.5066282746310002)
                           + TA_OUTLIER * ta_tail[s])
    return ll


@nb.njit(**_JIT)
def _fix(cells, level, out):
    """The fix of one request (rows of ``cells`` in CELL_FIELDS order) into ``out`` (FIX_FIELDS)."""
    m = cells.shape[0]
    lat0 = 0.0
    lon0 = 0.0
    for j in range(m):  # longitudes relative to the first cell's (a request across 180 degrees stays whole)
        lat0 += cells[j, 0]
        lon0 += (cells[j, 1] - cells[0, 1] + 540.0) % 360.0 - 180.0
    lat0 /= m
    lon0 = cells[0, 1] + lon0 / m
    ky = EARTH_M * math.pi / 180.0
    kx = ky * math.cos(math.radians(lat0))
    # sites: cells within 1 m of each other share one
    site = np.empty(m, np.int64)
    sx = np.empty(m)
    sy = np.empty(m)
    ns = 0
    for j in range(m):
        x = ((cells[j, 1] - lon0 + 540.0) % 360.0 - 180.0) * kx
        y = (cells[j, 0] - lat0) * ky
        k = 0
        while k < ns and math.hypot(x - sx[k], y - sy[k]) > 1.0:
            k += 1
        if k == ns:
            sx[ns], sy[ns] = x, y
            ns += 1
        site[j] = k
    # each site ranges by its first cell listed with a level: a phone lists its serving cell first, and the
    # others of a site are weaker by their antenna patterns or stronger by their lower bands, not by distance
    a = np.empty(ns)
    n = np.empty(ns)
    rss = np.empty(ns)
    var_s = np.empty(ns)
    best = np.full(ns, -1e300)
    site_az = np.full(ns, np.nan)
    site_var = 0.0
    reach = np.full(ns, MAX_REACH_M)
    ta_site = np.zeros(ns, np.bool_)
    ta_mu = np.zeros(ns)
    ta_sd = np.ones(ns)
    for j in range(m):
        radio = int(cells[j, 2])
        s = site[j]
        aj, sd_own, sd_env = _intercept(cells[j, 3], cells[j, 6], cells[j, 7])
        level_j = cells[j, 11]
        extra = 0.0
        rank = 1.0
        if level_j != level_j:
            level_j = _RADIO_TYPICAL[radio]
            extra = MISSING_DB * MISSING_DB
            rank = 0.0  # a cell with a level ranks first
        if rank > best[s]:
            best[s] = rank
            a[s], n[s], rss[s] = aj, cells[j, 4], level_j
            var_s[s] = SITE_DB ** 2 + CELL_DB ** 2 + sd_own * sd_own + sd_env * sd_env + extra
        if cells[j, 10] == cells[j, 10] and site_az[s] != site_az[s]:  # the site's first sector listed
            site_az[s] = cells[j, 10]
        rng = cells[j, 8]
        if rng == rng and rng > 0.0:  # twice the table's range bounds the site's reach
            reach[s] = min(reach[s], max(2.0 * rng, 1000.0))
        step = _RADIO_TA[radio]
        ta = cells[j, 12]
        if ta == ta and step == step:
            sd = math.sqrt(step * step / 12.0 + step * step + TA_FLOOR_M ** 2)
            if not ta_site[s] or sd < ta_sd[s]:
                ta_site[s], ta_mu[s], ta_sd[s] = True, (ta + 0.5) * step, sd
        changeable = cells[j, 9]
        if changeable == 1.0:
            site_var += max(100.0, AVERAGED_SITE * (rng if rng == rng else 500.0)) ** 2
        else:
            site_var += EXACT_SITE_M ** 2
    site_var /= m
    ta_tail = np.empty(ns)
    for s in range(ns):
        # the reach: 2.5 sigma beyond the level's distance, at least a timing-advance ring's far side
        sigma = math.sqrt(var_s[s])
        far = 1000.0 * 10.0 ** ((a[s] - rss[s] + 2.5 * sigma) / n[s])
        reach[s] = max(min(reach[s], far), MIN_REACH_M)
        if ta_site[s]:
            reach[s] = max(reach[s], ta_mu[s] + 3.0 * ta_sd[s])
        ta_tail[s] = 1.0 / reach[s]
    inv_sd = 1.0 / np.sqrt(var_s)
    kappa = SECTOR_LOSS_DB * inv_sd
    rows = np.empty((ns, _Z_N + 1))
    for s in range(ns):
        rows[s] = _level_row(kappa[s])
    sin_az = np.sin(np.radians(site_az))
    cos_az = np.cos(np.radians(site_az))
    # the region: where every site reaches (their boxes' intersection; their union if it is empty)
    x0, x1, y0, y1 = -1e300, 1e300, -1e300, 1e300
    for s in range(ns):
        x0, x1 = max(x0, sx[s] - reach[s]), min(x1, sx[s] + reach[s])
        y0, y1 = max(y0, sy[s] - reach[s]), min(y1, sy[s] + reach[s])
    if x0 >= x1 or y0 >= y1:
        x0, x1, y0, y1 = 1e300, -1e300, 1e300, -1e300
        for s in range(ns):
            x0, x1 = min(x0, sx[s] - reach[s]), max(x1, sx[s] + reach[s])
            y0, y1 = min(y0, sy[s] - reach[s]), max(y1, sy[s] + reach[s])
    logd = np.empty(ns)
    G = GRID
    ll = np.empty(G * G)
    px = np.empty(G * G)
    py = np.empty(G * G)
    w = np.empty(G * G)
    for it in range(PASSES):
        hx = (x1 - x0) / G
        hy = (y1 - y0) / G
        best = -1e300
        for i in range(G):
            for k in range(G):
                p = i * G + k
                px[p] = x0 + (i + 0.5) * hx
                py[p] = y0 + (k + 0.5) * hy
                ll[p] = _loglik(px[p], py[p], sx, sy, a, n, rss, inv_sd, kappa, rows, site_az, sin_az, cos_az,
                                ta_site, ta_mu, ta_sd, ta_tail, ns, logd)
                best = max(best, ll[p])
        for p in range(G * G):
            w[p] = math.exp(ll[p] - best)
        if it == PASSES - 1:
            break
        # the next grid: the cells holding the posterior's mass (weight above 1e-4 of the peak), one cell wider
        nx0, nx1, ny0, ny1 = 1e300, -1e300, 1e300, -1e300
        for p in range(G * G):
            if w[p] > 1e-4:
                nx0, nx1 = min(nx0, px[p] - 1.5 * hx), max(nx1, px[p] + 1.5 * hx)
                ny0, ny1 = min(ny0, py[p] - 1.5 * hy), max(ny1, py[p] + 1.5 * hy)
        nx0, nx1, ny0, ny1 = max(nx0, x0), min(nx1, x1), max(ny0, y0), min(ny1, y1)
        if (nx1 - nx0) > 0.8 * (x1 - x0) and (ny1 - ny0) > 0.8 * (y1 - y0):
            break
        x0, x1, y0, y1 = nx0, nx1, ny0, ny1
    total = 0.0
    ex = 0.0
    ey = 0.0
    for p in range(G * G):
        total += w[p]
        ex += w[p] * px[p]
        ey += w[p] * py[p]
    ex /= total
    ey /= total
    vee = 0.0
    ven = 0.0
    vnn = 0.0
    dist = np.empty(G * G)
    for p in range(G * G):
        dx, dy = px[p] - ex, py[p] - ey
        vee += w[p] * dx * dx
        ven += w[p] * dx * dy
        vnn += w[p] * dy * dy
        dist[p] = math.hypot(dx, dy)
    # a grid cell's own spread (uniform over hx x hy) and the site positions' uncertainty
    vee = vee / total + hx * hx / 12.0 + site_var
    vnn = vnn / total + hy * hy / 12.0 + site_var
    ven /= total
    order = np.argsort(dist)
    acc = 0.0
    radius = dist[order[-1]]
    for p in range(G * G):
        acc += w[order[p]]
        if acc >= level * total:
            radius = dist[order[p]]
            break
    cell_r2 = (hx * hx + hy * hy) / 12.0 + site_var
    out[0] = min(max(lat0 + ey / ky, -90.0), 90.0)
    out[1] = (lon0 + ex / kx + 540.0) % 360.0 - 180.0
    out[2] = math.sqrt(radius * radius - 2.0 * math.log(1.0 - level) * cell_r2)
    out[3] = vee
    out[4] = ven
    out[5] = vnn
    out[6] = ns


@nb.njit(**_JIT)
def _fixes(cells, offsets, level, out):
    for b in range(len(offsets) - 1):
        _fix(cells[offsets[b]:offsets[b + 1]], level, out[b])


def locate_cells(cells, offsets=None, *, level: float = CONFIDENCE) -> np.ndarray:
    """Positions from scans of cells (the posterior of the module doc), one row per scan.

    Parameters
    ----------
    cells : array_like or mapping
        (n, 13) float array, one row per cell heard, the columns CELL_FIELDS (or a mapping / DataFrame
        with those columns):
               lat, lon          the cell's site (WGS-84 degrees; latitudes within +-85)
               radio             radio code (index into RADIOS: 0 gsm, 1 wcdma, 2 lte, 3 nr, 4 cdma)
               intercept_dbm, slope_db   the prior path-loss model (:func:`signal_prior`)
               fit_offset_db     the table's fit of the cell (:func:`signal_fit`), NaN: none (pooled by its
                                 area into area_offset_db; alone it is noisier than the prior)
               area_fits, area_offset_db   the number and mean of the fits of the cell's location area
                                 (0 / NaN: none)
               range_m           the table's range (NaN: unknown), changeable 1 (averaged position) / 0 / NaN
               azimuth_deg       the sector's azimuth (NaN: omnidirectional or unknown)
               rss_dbm           the level the phone reports (NaN: none), ta its timing advance (NaN: none)
    offsets : array_like of int, shape (B + 1,), optional
        Scan b is rows offsets[b]:offsets[b + 1] (default: all rows are one scan).
    level : float, optional
        The confidence level of the accuracy radius (default CONFIDENCE = 0.68).

    Returns
    -------
    ndarray, shape (B, 7)
        Columns FIX_FIELDS: lat, lon (degrees), accuracy_m (the radius holding the true position with
        probability ``level``), the covariance var_e, cov_en, var_n (m^2) of the position, and the
        number of distinct sites.

    Raises
    ------
    ParameterError, ShapeError
        A column out of its range, a table of the wrong shape, offsets that do not cover the rows.
    """
    table = check_cells(cells)
    level = as_real("level", level, low=0.01, high=0.999)
    if offsets is None:  # one scan (a geolocation request): nothing to check
        off = np.array([0, len(table)], dtype=np.int64)
    else:
        off = as_array("offsets", offsets, ndim=1, low=0, high=len(table))
        if len(off) < 1 or off[0] != 0 or off[-1] != len(table) or np.any(np.diff(off) < 1) or \
                np.any(off != np.round(off)):
            raise ParameterError(f"offsets: expected increasing integers from 0 to {len(table)} (every scan at "
                                 "least one cell), got " + (repr(off.tolist()) if len(off) < 8 else
                                                            f"{len(off)} values"))
    out = np.empty((len(off) - 1, len(FIX_FIELDS)))
    _fixes(table, off.astype(np.int64), level, out)
    return out


#: valid ranges of the columns (NaN allowed where the column doc says "NaN: ...")
_RANGES = {"lat": (-85.0, 85.0, False), "lon": (-180.0, 180.0, False), "radio": (0, len(RADIOS) - 1, False),
           "intercept_dbm": (-250.0, 100.0, False), "slope_db": (1.0, 100.0, False),
           "fit_offset_db": (-100.0, 100.0, True), "area_fits": (0.0, 1e12, False),
           "area_offset_db": (-100.0, 100.0, True), "range_m": (0.0, 1e7, True), "changeable": (0, 1, True),
           "azimuth_deg": (0.0, 360.0, True), "rss_dbm": (-200.0, 0.0, True), "ta": (0.0, 1e5, True)}


_LO = np.array([_RANGES[c][0] for c in CELL_FIELDS], dtype=float)
_HI = np.array([_RANGES[c][1] for c in CELL_FIELDS], dtype=float)
_NAN_OK = np.array([_RANGES[c][2] for c in CELL_FIELDS])
_RADIO = CELL_FIELDS.index("radio")


def check_cells(cells) -> np.ndarray:
    """A table of cells for :func:`locate_cells`, its columns checked against their ranges.

    Parameters
    ----------
    cells : array_like or mapping
        (n, 13) float array, one row per cell, the columns CELL_FIELDS (or a mapping / DataFrame with
        those columns), as :func:`locate_cells` takes them.

    Returns
    -------
    ndarray, shape (n, 13)
        The table as a C-contiguous float64 array (``cells`` itself when it is one).

    Raises
    ------
    ParameterError, ShapeError, DTypeError, NonFiniteError
        A column out of its range (naming it and the row), a table of the wrong shape or type.
    """
    if hasattr(cells, "keys") and not isinstance(cells, np.ndarray):
        missing = [c for c in CELL_FIELDS if c not in cells.keys()]
        if missing:
            raise ShapeError(f"cells: missing columns {missing} (expected {', '.join(CELL_FIELDS)})")
        cells = np.column_stack([np.asarray(cells[c], dtype=float) for c in CELL_FIELDS])
    if isinstance(cells, np.ndarray) and cells.dtype == np.float64 and cells.ndim == 2 and \
            cells.shape[0] >= 1 and cells.shape[1] == len(CELL_FIELDS) and cells.flags.c_contiguous and \
            _all_in_range(cells, _LO, _HI, _NAN_OK):
        return cells   # a request's few cells: one compiled pass, no temporaries
    table = as_array("cells", cells, ndim=2, allow_nan=True)
    if table.shape[1] != len(CELL_FIELDS) or table.shape[0] < 1:
        raise ShapeError(f"cells: expected an (n, {len(CELL_FIELDS)}) table with n >= 1 (columns "
                         f"{', '.join(CELL_FIELDS)}), got shape {table.shape}")
    table = np.ascontiguousarray(table, dtype=float)
    ok = ((table >= _LO) & (table <= _HI)) | (_NAN_OK & np.isnan(table))  # one pass over the table
    if not ok.all():
        i, row = (int(v[0]) for v in np.nonzero(~ok.T))  # the first column with a bad value, its first row
        name = CELL_FIELDS[i]
        lo, hi, nan_ok = _RANGES[name]
        raise ParameterError(f"cells: column {name} expects {lo:g}..{hi:g}{' or NaN' if nan_ok else ''}, got "
                             f"{table[row, i]!r} in row {row}")
    radio = table[:, _RADIO]
    if np.any(radio != np.round(radio)):
        raise ParameterError("cells: column radio expects integer radio codes (RADIOS)")
    return table


@nb.njit(**_JIT)
def _all_in_range(table, lo, hi, nan_ok):
    """Whether every value of ``table`` is within its column's [lo, hi] (or NaN where nan_ok) and the radio
    codes are integers (False: :func:`check_cells` looks closer and says what is wrong)."""
    for i in range(table.shape[0]):
        for j in range(table.shape[1]):
            v = table[i, j]
            if v != v:
                if not nan_ok[j]:
                    return False
            elif not lo[j] <= v <= hi[j]:
                return False
        if table[i, _RADIO] != math.floor(table[i, _RADIO]):
            return False
    return True
