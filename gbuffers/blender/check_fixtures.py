"""Independent check of the Blender fixtures: numpy + OpenImageIO only.

    /work/venv/bin/python gbuffers/blender/check_fixtures.py [FILE.exr ...]

For each EXR (default: the three in this folder) it recomputes, in float64,
the direct diffuse radiance of the radius-0 point lights in fixtures.json
from the Position, Normal and Diffuse Color passes,

    L = sum_lights albedo * (1/pi) * color * P/(4 pi) * max(n.l, 0) / d^2,

and compares it with Combined (and Combined_<group> with each group's sum)
on fully covered pixels (alpha == 1).  "Pure" pixels are those whose Diffuse
Color equals one object's base colour (to 1e-4), i.e. not straddling two
objects.  It also reports the edge pixels (0 < alpha < 1): how many have
Position == (0, 0, 0) and whether Diffuse Color and Normal are premultiplied
by alpha there.  It does not use clphong.
"""

import json
import os
import sys

import numpy as np
import OpenImageIO as oiio

HERE = os.path.dirname(os.path.abspath(__file__))


def read_channels(path):
    """{channel name: (H, W) float64} over every part of the file."""
    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise RuntimeError(oiio.geterror())
    out, index = {}, 0
    while inp.seek_subimage(index, 0):
        spec = inp.spec()
        pixels = inp.read_image(index, 0, 0, spec.nchannels, "float")
        for c, name in enumerate(spec.channelnames):
            out[name] = np.asarray(pixels[:, :, c], dtype=np.float64)
        index += 1
    inp.close()
    return out


def stack(ch, prefix, names):
    return np.stack([ch[prefix + n] for n in names], axis=-1)


def relative(a, b, mask):
    """Relative error |a-b|/b of the luminance-ish sum over RGB, on mask."""
    sa, sb = a.sum(-1)[mask], b.sum(-1)[mask]
    return np.abs(sa - sb) / sb, sa / sb


def check(path, facts):
    ch = read_channels(path)
    lay = "ViewLayer."
    diff = "Diffuse Color" if lay + "Diffuse Color.R" in ch else "DiffCol"
    rgb = ["R", "G", "B"]
    alpha = ch[lay + "Combined.A"]
    combined = stack(ch, lay + "Combined.", rgb)
    pos = stack(ch, lay + "Position.", ["X", "Y", "Z"])
    nrm = stack(ch, lay + "Normal.", ["X", "Y", "Z"])
    albedo = stack(ch, lay + diff + ".", rgb)

    full = alpha == 1.0
    colors = np.array([o["color"] for o in facts["objects"]])
    dist = np.abs(albedo[..., None, :] - colors[None, None]).max(-1)
    pure = full & (dist.min(-1) < 1e-4)

    n = nrm / np.maximum(np.linalg.norm(nrm, axis=-1, keepdims=True), 1e-30)
    per_group = {}
    expected = np.zeros_like(combined)
    min_abs_cos = np.full(alpha.shape, np.inf)
    for light in facts["lights"]:
        to = np.asarray(light["position"], dtype=np.float64) - pos
        d2 = (to * to).sum(-1)
        l = to / np.sqrt(d2)[..., None]
        cos_signed = (n * l).sum(-1)
        min_abs_cos = np.minimum(min_abs_cos, np.abs(cos_signed))
        cos = np.maximum(cos_signed, 0.0)
        e = (albedo / np.pi * np.asarray(light["color"]) *
             (light["power"] / (4 * np.pi) * cos / d2)[..., None])
        expected += e
        per_group[light["group"]] = per_group.get(light["group"], 0) + e

    print(os.path.basename(path))
    lit_level = 1e-3 * expected.sum(-1)[full].max()
    # Away from every light's terminator: there the pixel average of
    # max(n.l, 0) over the pixel footprint differs from its value at the
    # centre, which is all that the passes carry.
    clear = pure & (min_abs_cos > 0.1)
    masks = (("alpha==1", full), ("alpha==1, pure", pure),
             ("pure, |n.l|>0.1", clear))
    for label, mask0 in masks:
        lit = mask0 & (expected.sum(-1) > lit_level)
        err, ratio = relative(combined, expected, lit)
        print(f"  Combined vs L [{label:15}] {lit.sum():4d} lit px: rel err "
              f"mean {err.mean():.4f} median {np.median(err):.4f} "
              f"max {err.max():.4f}; Combined/L mean {ratio.mean():.4f}")
    for group, e in per_group.items():
        got = stack(ch, f"{lay}Combined_{group}.", rgb)
        for label, mask0 in masks[1:]:
            lit = mask0 & (e.sum(-1) > lit_level)
            err, ratio = relative(got, e, lit)
            print(f"  Combined_{group:4} vs its lights [{label:15}] "
                  f"{lit.sum():4d} lit px: rel err mean {err.mean():.4f} "
                  f"max {err.max():.4f}; ratio mean {ratio.mean():.4f}")
    groups_sum = sum(stack(ch, f"{lay}Combined_{g}.", rgb) for g in per_group)
    worst = np.abs(groups_sum - combined).max()
    print(f"  max |Combined - sum of Combined_<group>| = {worst:.3g}")

    # Edge pixels.
    edge = (alpha > 0) & (alpha < 1)
    zero_pos = edge & np.all(pos == 0, axis=-1)
    print(f"  edge px (0<alpha<1): {edge.sum()}; with Position == (0,0,0): "
          f"{zero_pos.sum()}; alpha==0 px: {(alpha == 0).sum()} (Position "
          f"all zero there: {bool(np.all(pos[alpha == 0] == 0))})")
    a = alpha[edge][:, None]
    raw = np.abs(albedo[edge][:, None, :] - colors[None]).max(-1).min(-1)
    unp = np.abs((albedo[edge] / a)[:, None, :] - colors[None]).max(-1).min(-1)
    print(f"  edge Diffuse Color: matches an object colour as stored in "
          f"{(raw < 1e-3).sum()} px, after dividing by alpha in "
          f"{(unp < 1e-3).sum()} px (of {edge.sum()}; tolerance 1e-3)")
    nlen = np.linalg.norm(nrm[edge], axis=-1)
    inner = np.linalg.norm(nrm[pure], axis=-1)
    print(f"  edge |Normal|/alpha: median {np.median(nlen / alpha[edge]):.4f}"
          f" (|Normal| median {np.median(nlen):.4f}, alpha median "
          f"{np.median(alpha[edge]):.4f}); interior |Normal| median "
          f"{np.median(inner):.4f}")
    nonzero = edge & ~zero_pos
    print(f"  edge Position: {nonzero.sum()} non-zero (the unfiltered "
          f"pixel-centre hit of sample 0, not alpha-weighted); alpha of the "
          f"zero ones <= {alpha[zero_pos].max():.3f}, of the non-zero ones "
          f">= {alpha[nonzero].min():.3f}")
    return ch


def main():
    with open(os.path.join(HERE, "fixtures.json")) as f:
        facts = json.load(f)
    paths = sys.argv[1:] or [os.path.join(HERE, n) for n in
                             ("cycles-5.0.exr", "cycles-5.0-interleaved.exr",
                              "cycles-4.5.exr")]
    loaded = [check(p, facts) for p in paths]
    if len(loaded) >= 2:
        for p, ch in zip(paths[1:], loaded[1:]):
            common = sorted(set(ch) & set(loaded[0]))
            same = all(np.array_equal(ch[k], loaded[0][k]) for k in common)
            worst = max(np.abs(ch[k] - loaded[0][k]).max() for k in common)
            print(f"{os.path.basename(p)} vs {os.path.basename(paths[0])}: "
                  f"{len(common)} common channels, bit-identical: {same}, "
                  f"max |difference| {worst:.3g}")


if __name__ == "__main__":
    main()
