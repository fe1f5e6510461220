"""Issue #42 item 1: two ways to find the specular lobe where SfM normals are wrong.

1. Sparkle density: P(pixel in S | theta_h) = a exp(-tan^2 theta_h / s^2) (optionally
   / cos^4), fitted by maximum likelihood (binomial) over every valid pixel of every frame
   (`sparkle_sigma`; the library's version, with Beckmann's D cos theta_h = / cos^3, a <= 1
   and its checks, is `ctjax.specular.sparkle_density`).
2. Normals anchored at the highlights: at each S component's peak N = H; the SfM normals of
   the component and its surroundings are rotated by the rotation taking the SfM normal at
   the peak onto H, and `fit_capture` runs on the corrected capture (`anchored_normals`).

`sparkly_capture` turns a synthetic capture (`ctjax synth`) into one whose highlights are
sparkles (one facet per pixel, Beckmann-tilted), `perturbed_normals` adds a controlled,
smooth error to the normals.

    python benchmarks/lobe_ideas.py CAPTURE [--truth-normals CAPTURE] [--fit] [--anchor]
        [--halves] [--radius PX]
    python benchmarks/lobe_ideas.py SYNTHETIC --make-sparkly OUT --sigma 0.2

Measured (2-core CPU, 2026-11-26; synthetic: `ctjax synth --width 320 --height 256
--frames 8 --seed 1`, SfM by `ctjax reconstruct`, 1 degree RMS off; real: 12 frames at
640 px, /tmp/rv as benchmarks/real_video.py builds it):

- Sparkles, sigma 0.209 / 0.404 (meso 0.2 / 0.4 with a sharp 0.06 facet lobe):
  `sparkle_density` 0.204 / 0.394 on the true normals, 0.204 / 0.406 on SfM normals
  (halves 0.19-0.22 / 0.39-0.42); `ctjax fit` on the same captures: `no_lobe`
  (F_tilde ~0.002, sigma 0.22-0.33), even with the true normals.
- Smooth lobe (the synth's own highlights): S is a disc cut by the highlight rule, a -> 1,
  sigma 0.24-0.28 whatever the truth (0.2 or 0.4): refused as `solid_highlights`.
- Normal error (smooth random, 20 px): sigma_fit^2 ~ sigma^2 + e^2; corrected within 5%
  at 5 degrees RMS, 15% at 10, not at 20.
- Anchoring: on the true normals it moves them 1 (sigma 0.2) to 5 degrees (0.4: the
  intensity peak is not where N = H) and biases the fit (0.400 -> 0.452, F_tilde -15%);
  on SfM normals the error near S grows (2.6 -> 3.4, 1.6 -> 5.7 degrees RMS); on sparkles
  it aligns the facets, not the surface (11-25 degrees) and reports a false lobe (0.79-0.86,
  `successful`). Real frames: normals rotated by 35 (lap video) and 26 (sinus) degrees
  (median) and the fit stays `no_lobe` / `unstable` / `at_bound`.
"""

import argparse
import dataclasses
import json
import sys
import time

import cv2
import numpy as np
from scipy import optimize

from ctjax.io import load_capture
from ctjax.specular import MaskOptions, capture_sets


def view_directions(camera, shape) -> np.ndarray:
    """(H, W, 3) unit V (surface -> camera) of every pixel, camera frame (light at the lens:
    H = V)."""
    h, w = shape
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    ray = np.stack(
        [
            (u - float(camera.cx)) / float(camera.fx),
            (v - float(camera.cy)) / float(camera.fy),
            np.ones_like(u),
        ],
        axis=-1,
    )
    return -ray / np.linalg.norm(ray, axis=-1, keepdims=True)


def frame_angles(capture, sets, normals_of=None):
    """Per frame: (theta_h of the valid pixels, their S flags)."""
    out = []
    for k, (frame, s) in enumerate(zip(capture.frames, sets, strict=True)):
        normals = frame.normals if normals_of is None else normals_of[k]
        h_vec = view_directions(capture.camera, frame.image.shape[:2])
        valid = frame.geometry_mask & ~s.saturated
        cos = np.clip(np.sum(normals * h_vec, axis=-1), -1.0, 1.0)
        valid &= np.isfinite(cos) & (cos > 0.05)
        out.append((np.arccos(cos[valid]), s.specular[valid]))
    return out


def sparkle_sigma(angles, bins: int = 400, max_deg: float = 80.0, cos4: bool = False) -> dict:
    """Binomial maximum likelihood of P(S | theta_h) = a exp(-tan^2 theta_h / s^2)
    (times 1 / cos^4 theta_h with `cos4`: Beckmann's D)."""
    theta = np.concatenate([a for a, _ in angles])
    in_s = np.concatenate([s for _, s in angles])
    edges = np.linspace(0.0, np.radians(max_deg), bins + 1)
    total, _ = np.histogram(theta, edges)
    hits, _ = np.histogram(theta[in_s], edges)
    centre = 0.5 * (edges[1:] + edges[:-1])
    c = np.tan(centre) ** 2
    keep = total > 0
    extra = -4 * np.log(np.cos(centre[keep])) if cos4 else 0.0

    def nll(x):
        log_a, log_s = x
        p = np.exp(log_a + extra - c[keep] / np.exp(2 * log_s))
        p = np.clip(p, 1e-12, 1 - 1e-12)
        return -np.sum(hits[keep] * np.log(p) + (total[keep] - hits[keep]) * np.log1p(-p))

    best = None
    for s0 in (0.05, 0.1, 0.2, 0.4, 0.8):
        r = optimize.minimize(nll, [np.log(0.5), np.log(s0)], method="Nelder-Mead")
        if best is None or r.fun < best.fun:
            best = r
    log_a, log_s = best.x
    # Curvature of the profile in log s: a standard error.
    eps = 1e-3
    f0 = best.fun
    f1 = nll([log_a, log_s + eps])
    f2 = nll([log_a, log_s - eps])
    curv = (f1 + f2 - 2 * f0) / eps**2
    s_theta = theta[in_s]
    return {
        "sigma": float(np.exp(log_s)),
        "a": float(np.exp(log_a)),
        "sigma_rel_stderr": float(1 / np.sqrt(curv)) if curv > 0 else None,
        "n_valid": int(theta.size),
        "n_S": int(in_s.sum()),
        "S_theta_deg_median": float(np.degrees(np.median(s_theta))) if s_theta.size else None,
        "S_theta_deg_p90": float(np.degrees(np.quantile(s_theta, 0.9))) if s_theta.size else None,
    }


def _rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit a onto unit b."""
    v = np.cross(a, b)
    c = float(np.dot(a, b))
    s = np.linalg.norm(v)
    if s < 1e-12:
        return np.eye(3)
    k = v / s
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * kx + (1 - c) * kx @ kx


def anchored_normals(capture, sets, radius_px: float = 8.0, core: float = 0.98):
    """Per frame: normals rotated, around each S component, so that N = H at its peak (the
    centroid of the component's pixels within `core` of its brightest luminance, snapped to
    the nearest such pixel). Returns (normals list, per-frame rotation angles, degrees)."""
    out, angles = [], []
    for frame, s in zip(capture.frames, sets, strict=True):
        normals = np.array(frame.normals, np.float64)
        h_vec = view_directions(capture.camera, frame.image.shape[:2])
        if not s.specular.any():
            out.append(normals.astype(np.float32))
            angles.append([])
            continue
        n, labels = cv2.connectedComponents(s.specular.astype(np.uint8), connectivity=8)
        # Each pixel's nearest S component, and its distance.
        distance, nearest = cv2.distanceTransformWithLabels(
            (~s.specular).astype(np.uint8), cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_CCOMP
        )
        # DIST_LABEL_CCOMP labels the zero-pixel components itself: map them to ours.
        map_label = np.zeros(nearest.max() + 1, np.int64)
        map_label[nearest[s.specular]] = labels[s.specular]
        owner = map_label[nearest]
        lum = frame.image @ np.array([0.2126, 0.7152, 0.0722], np.float32)
        valid = frame.geometry_mask
        near = distance <= radius_px
        frame_angles_deg = []
        for k in range(1, n):
            comp = (labels == k) & valid
            if not comp.any():
                continue
            vv, uu = np.nonzero(comp)
            values = lum[vv, uu]
            bright = values >= core * values.max()
            cu, cv_ = uu[bright].mean(), vv[bright].mean()
            j = np.argmin((uu[bright] - cu) ** 2 + (vv[bright] - cv_) ** 2)
            pu, pv = uu[bright][j], vv[bright][j]
            n_peak = normals[pv, pu]
            rot = _rotation(n_peak / np.linalg.norm(n_peak), h_vec[pv, pu])
            region = near & (owner == k) & valid
            normals[region] = normals[region] @ rot.T
            frame_angles_deg.append(
                float(np.degrees(np.arccos(np.clip(np.trace(rot) / 2 - 0.5, -1, 1))))
            )
        out.append(normals.astype(np.float32))
        angles.append(frame_angles_deg)
    return out, angles


def with_normals(capture, normals):
    frames = tuple(
        dataclasses.replace(f, normals=n) for f, n in zip(capture.frames, normals, strict=True)
    )
    return dataclasses.replace(capture, frames=frames)


def subset(capture, parity):
    return dataclasses.replace(capture, frames=capture.frames[parity::2])


def normal_error_deg(capture, truth, sets=None, near_px=None):
    """Angles between the capture's normals and the truth's (median, RMS, in degrees), on
    all valid pixels, or within `near_px` of S."""
    errs = []
    for k, (f, t) in enumerate(zip(capture.frames, truth.frames, strict=True)):
        m = f.geometry_mask & t.geometry_mask
        if sets is not None and near_px is not None and sets[k].specular.any():
            d = cv2.distanceTransform((~sets[k].specular).astype(np.uint8), cv2.DIST_L2, 5)
            m &= d <= near_px
        cos = np.clip(np.sum(f.normals[m] * t.normals[m], axis=-1), -1, 1)
        errs.append(np.degrees(np.arccos(cos)))
    e = np.concatenate(errs)
    return {"median": float(np.median(e)), "rms": float(np.sqrt(np.mean(e**2)))}


def _fit(capture):
    from ctjax.estimation import fit_capture

    t = time.time()
    est = fit_capture(capture)
    d = est.to_json() if hasattr(est, "to_json") else dict(est)
    return {
        "sigma": d.get("sigma"),
        "F_tilde": d.get("F_tilde"),
        "status": d.get("status"),
        "seconds": round(time.time() - t, 1),
    }


def main(argv=None):
    p = argparse.ArgumentParser()
    p.add_argument("capture")
    p.add_argument("--truth-normals", help="capture whose normals are the truth")
    p.add_argument("--anchor", action="store_true", help="idea 2: fit on anchored normals")
    p.add_argument("--fit", action="store_true", help="ctjax fit on the capture as it is")
    p.add_argument("--halves", action="store_true", help="also the even and odd frames apart")
    p.add_argument("--radius", type=float, default=8.0)
    p.add_argument("--make-sparkly", metavar="OUT", help="write a sparkly copy and exit")
    p.add_argument("--sigma", type=float, default=0.2, help="with --make-sparkly")
    args = p.parse_args(argv)
    if args.make_sparkly:
        print(sparkly_capture(args.capture, args.make_sparkly, args.sigma, sigma_micro=0.06, F=0.1))
        return
    capture = load_capture(args.capture)
    sets = capture_sets(capture, MaskOptions())
    parts = {"all": (capture, sets)}
    if args.halves:
        parts["even"] = (subset(capture, 0), sets[0::2])
        parts["odd"] = (subset(capture, 1), sets[1::2])
    report = {}
    truth = load_capture(args.truth_normals) if args.truth_normals else None
    if truth is not None:
        report["normal_error_deg"] = normal_error_deg(capture, truth)
        report["normal_error_deg_near_S"] = normal_error_deg(capture, truth, sets, 8)
        report["sparkle_truth_normals"] = sparkle_sigma(
            frame_angles(capture, sets, [f.normals for f in truth.frames])
        )
    for name, (cap, st) in parts.items():
        row = {"sparkle": sparkle_sigma(frame_angles(cap, st))}
        if args.fit:
            row["fit"] = _fit(cap)
        if args.anchor:
            normals, rot = anchored_normals(cap, st, args.radius)
            flat = [a for r in rot for a in r]
            row["anchor_rotation_deg"] = {
                "n": len(flat),
                "median": float(np.median(flat)) if flat else None,
                "p90": float(np.quantile(flat, 0.9)) if flat else None,
            }
            anchored = with_normals(cap, normals)
            row["sparkle_anchored"] = sparkle_sigma(frame_angles(anchored, st))
            if truth is not None and name == "all":
                row["anchored_normal_error_deg_near_S"] = normal_error_deg(anchored, truth, st, 8)
            row["fit_anchored"] = _fit(anchored)
        report[name] = row
        print(name, json.dumps(row), flush=True)
    json.dump(report, sys.stdout, indent=1)
    print()


def sparkly_capture(
    source,
    out,
    sigma_meso: float,
    sigma_micro: float = 0.03,
    F: float = 0.05,
    corr_px: float = 1.5,
    seed: int = 0,
    noise_levels: float = 1.0,
):
    """A copy of a synthetic capture whose highlights are sparkles: every pixel sees one
    facet, its normal the surface's (normals/, kept) tilted by a Beckmann slope of
    roughness `sigma_meso` (smoothed over `corr_px`, so sparkles span a few pixels), lit by
    a sharp lobe (`sigma_micro`, F_tilde `F`) and the true albedo maps' diffuse term.
    truth.json's sigma becomes sqrt(sigma_meso^2 + sigma_micro^2) (the lobe seen by a
    pixel-averaged model)."""
    import shutil
    from pathlib import Path

    from ctjax.io import write_rgb

    source, out = Path(source), Path(out)
    if out.exists():
        shutil.rmtree(out)
    shutil.copytree(source, out)
    capture = load_capture(source)
    rng = np.random.default_rng(seed)
    for frame in capture.frames:
        h, w = frame.image.shape[:2]
        n = frame.normals.astype(np.float64)
        albedo = np.load(source / "albedo" / f"{frame.name}.npy").astype(np.float64)
        slopes = []
        for _ in range(2):
            z = rng.normal(size=(h, w))
            z = cv2.GaussianBlur(z, (0, 0), corr_px)
            slopes.append(z / z.std() * sigma_meso / np.sqrt(2))
        # Tangent frame of the macro normal.
        t1 = np.cross(n, np.array([0.0, 1.0, 0.0]))
        t1 /= np.linalg.norm(t1, axis=-1, keepdims=True)
        t2 = np.cross(n, t1)
        facet = n - slopes[0][..., None] * t1 - slopes[1][..., None] * t2
        facet /= np.linalg.norm(facet, axis=-1, keepdims=True)
        v = view_directions(capture.camera, (h, w))
        cos_macro = np.clip(np.sum(n * v, -1), 0, 1)
        cos_f = np.clip(np.sum(facet * v, -1), 1e-3, 1)
        tan2 = (1 - cos_f**2) / cos_f**2
        d = np.exp(-tan2 / sigma_micro**2) / (sigma_micro**2 * cos_f**4)
        spec = F * d / (np.pi * cos_f**2)
        linear = albedo / np.pi * cos_macro[..., None] + spec[..., None]
        linear = linear + rng.normal(0, noise_levels / 255, linear.shape)
        linear = np.where(np.isfinite(linear), linear, 0)
        write_rgb(out / "images" / f"{frame.name}.png", np.clip(linear, 0, 1))
    truth = json.loads((out / "truth.json").read_text())
    truth |= {
        "sigma": float(np.hypot(sigma_meso, sigma_micro)),
        "sigma_meso": sigma_meso,
        "sigma_micro": sigma_micro,
        "F_tilde": [F] * 3,
        "sparkles": "one facet per pixel (benchmarks/lobe_ideas.py sparkly_capture)",
    }
    (out / "truth.json").write_text(json.dumps(truth, indent=1))
    return out


def perturbed_normals(capture, rms_deg: float, corr_px: float = 20.0, seed: int = 0):
    """Every frame's normals tilted by a smooth random field (Gaussian-correlated over
    `corr_px`, RMS tilt `rms_deg`): the low-frequency error of SfM normals, controlled."""
    rng = np.random.default_rng(seed)
    out = []
    for frame in capture.frames:
        n = frame.normals.astype(np.float64)
        h, w = n.shape[:2]
        tilt = []
        for _ in range(2):
            z = cv2.GaussianBlur(rng.normal(size=(h, w)), (0, 0), corr_px)
            tilt.append(z / z.std() * np.tan(np.radians(rms_deg)) / np.sqrt(2))
        t1 = np.cross(n, np.array([0.0, 1.0, 0.0]))
        t1 /= np.linalg.norm(t1, axis=-1, keepdims=True)
        t2 = np.cross(n, t1)
        m = n + tilt[0][..., None] * t1 + tilt[1][..., None] * t2
        out.append((m / np.linalg.norm(m, axis=-1, keepdims=True)).astype(np.float32))
    return out


if __name__ == "__main__":
    main()
