"""The specular lobe in the light's colour (the dichromatic model) against one F_tilde per
channel (the paper's): does tying the lobe's colour steady sigma on real frames?

    .venv/bin/python benchmarks/lobe_colour.py CAPTURE [CAPTURE ...]

Each CAPTURE is reconstructed (`ctjax reconstruct`) or has depth and poses. A highlight
reflects the light's colour (tissue's Fresnel coefficient barely changes over the visible
range): in a white-balanced camera F_tilde is the same in R, G and B. With every point's
albedo free per channel, that model's sigma and F_tilde are exactly those fitted to the
channels' mean: write each linear observation y_c = m + d_c (m the mean, d_c summing to
0 over the channels) and the albedo likewise; the lobe adds the same to every channel, so
the sum of squares splits into 3 x the mean's (where the lobe is) plus the d_c's (a
Lambertian term alone), and the cross terms vanish. So `tied` is `fit`'s own estimator
(`fit_capture`, the albedo map) on the frames' channel mean, with S, S~ and the clipped
observations found on the colour frames first. Not exact where an albedo's nonnegativity
binds in one channel; and the lobe's gain where it shows (the status's) leaves out the
colour residual neither model explains, so `tied`'s status is not comparable with
`free`'s: compare sigma and the halves.

Prints per capture: sigma, its standard error, F_tilde, the status and the halves' sigma
(the fit's own split of the frames), for `free` (as `ctjax fit`) and `tied`. Measured on
2026-12-02 (docs/real-video.md, "The lobe in the light's colour"): sigma moved by at most
5% wherever a lobe is found, and on one SCARED stretch of six the odd half steadied.
"""

import argparse
import time

from ctjax.estimation import fit_capture
from ctjax.estimation._uniform_fit import DEFAULT_MASKS
from ctjax.io import load_capture
from ctjax.observations import Observations


def _fit(path: str, tied: bool) -> dict:
    obs = Observations.of(load_capture(path), DEFAULT_MASKS)
    obs.sets, obs.usable  # noqa: B018  (S, S~ and the clipped observations: colour frames)
    if tied:
        for frame in obs.frames:  # the linear images' channel mean, in place (loaded here)
            frame.image[...] = frame.image.mean(axis=-1, keepdims=True)
    started = time.perf_counter()
    fit = fit_capture(obs, DEFAULT_MASKS).to_json()
    fit["seconds"] = time.perf_counter() - started
    return fit


def _row(name: str, fit: dict) -> str:
    error = fit.get("sigma_stderr")
    halves = fit.get("halves") or {}
    split = " / ".join(f"{h['sigma']:.3f}" for h in halves.values()) or "-"
    return (
        f"  {name:5s} sigma {fit['sigma']:.4f} +- {error if error is None else round(error, 4)}"
        f"  F_tilde {[round(f, 4) for f in fit['F_tilde']]}  {fit['status']:12s}"
        f"  halves {split}  ({fit['seconds']:.0f} s)"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("captures", nargs="+")
    args = parser.parse_args()
    for path in args.captures:
        print(path)
        for name, tied in (("free", False), ("tied", True)):
            print(_row(name, _fit(path, tied)), flush=True)


if __name__ == "__main__":
    main()
