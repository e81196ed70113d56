"""Synthetic ground-truth subjects: an Anny body with random phenotype AND local changes, once
subdivided, with clothing, shoes and hair as displacement fields along the canonical normals,
garment wrinkles, and a procedural UV texture.

The detail is deliberately outside what reconstruction may use (6 phenotypes + offsets on the
coarse mesh): 256 local shape changes, and displacements on the 4× finer mesh.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from torch import Tensor

from monoavatar.body import REGIONS, BodyModel
from monoavatar.body.subdivide import Subdivision, subdivide
from monoavatar.core.camera import PinholeCamera
from monoavatar.render import rasterize, vertex_normals
from monoavatar.synth.anthropometry import measure_body, plausible
from monoavatar.synth.options import CLOTHING, HAIR_STYLES, VARIETIES

GARMENTS = ("skin", "top", "bottom", "hair", "shoes")
"""The garment classes of :attr:`Subject.garment`, by index."""

SKIN_TONES = np.array(
    [[0.95, 0.80, 0.69], [0.88, 0.69, 0.56], [0.78, 0.57, 0.44], [0.62, 0.43, 0.31],
     [0.45, 0.30, 0.21], [0.32, 0.21, 0.15]]
)  # fmt: skip
HAIR_COLOURS = np.array(
    [[0.05, 0.04, 0.04], [0.22, 0.14, 0.08], [0.45, 0.30, 0.16], [0.78, 0.64, 0.40],
     [0.55, 0.22, 0.10], [0.60, 0.60, 0.58]]
)  # fmt: skip


@dataclass
class SubjectSpec:
    """What a subject looks like; drawn by :func:`sample_subject`, all lengths in metres."""

    shape: np.ndarray  # (S,) shape parameters of the local-changes Anny model
    clothing: str
    top_colour: np.ndarray
    bottom_colour: np.ndarray
    pattern: str  # solid | stripes | checks
    skin: np.ndarray
    hair_colour: np.ndarray
    hair_volume: float  # metres of hair on the scalp
    sleeve: float  # 0 = none, 1 = to the wrist (fraction of shoulder→wrist)
    leg: float  # 0 = none, 1 = to the ankle (fraction of hip→ankle)
    top_thickness: float
    bottom_thickness: float
    wrinkle_amplitude: float
    wrinkle_seed: int
    skirt_flare: float = 0.0
    hair_style: str = "cropped"  # one of HAIR_STYLES
    shoe_height: float = 0.008  # metres of shoe on the foot
    extras: dict[str, float] = field(default_factory=dict)


#: sleeve and leg lengths (fractions of shoulder→wrist, hip→ankle) of each garment set
_LENGTHS = {"minimal": (0.0, 0.12), "tight": (0.25, 0.9), "tshirt-shorts": (0.35, 0.4),
            "longsleeve-trousers": (0.95, 0.95), "loose": (0.6, 0.95), "skirt": (0.3, 0.35)}


def sample_subject(
    rng: np.random.Generator, body: BodyModel, clothing: str | None = None,
    variety: str = "standard",
) -> SubjectSpec:
    """Draw a subject: phenotypes across Anny's range, random local changes, a garment set.
    ``variety="wide"``: the harder distribution of :func:`sample_wide_subject`."""
    if variety not in VARIETIES:
        raise ValueError(f"unknown variety {variety!r}; choose from {VARIETIES}")
    if variety == "wide":
        return sample_wide_subject(rng, body, clothing)
    if clothing is None:
        clothing = str(rng.choice(CLOTHING))
    if clothing not in CLOTHING:
        raise ValueError(f"unknown clothing {clothing!r}; choose from {CLOTHING}")
    shape = np.zeros(body.shape_dim)
    shape[:6] = rng.uniform(-0.35, 0.35, 6)  # gender, age, muscle, weight, height, proportions
    shape[0] = rng.choice([-0.45, 0.45]) + rng.uniform(-0.05, 0.05)  # mostly clear gender
    shape[1] = rng.uniform(-0.1, 0.3)  # adults
    if body.shape_dim > 6:  # local changes: sparse, moderate
        active = rng.random(body.shape_dim - 6) < 0.25
        shape[6:] = active * rng.uniform(-0.5, 0.5, body.shape_dim - 6)
    sleeve, leg = _LENGTHS[clothing]
    top_t, bottom_t, wrinkle = {
        "minimal": (0.002, 0.002, 0.0005), "tight": (0.004, 0.004, 0.001),
        "tshirt-shorts": (0.010, 0.010, 0.003), "longsleeve-trousers": (0.010, 0.012, 0.003),
        "loose": (0.022, 0.018, 0.005), "skirt": (0.008, 0.008, 0.002),
    }[clothing]  # fmt: skip
    flare = 0.12 if clothing == "skirt" else 0.0
    return SubjectSpec(
        shape=shape,
        clothing=clothing,
        **_appearance(rng, 0.035),
        sleeve=sleeve,
        leg=leg,
        top_thickness=top_t,
        bottom_thickness=bottom_t,
        wrinkle_amplitude=wrinkle,
        skirt_flare=flare,
    )


def _appearance(rng: np.random.Generator, max_hair: float) -> dict[str, Any]:
    """Colours, pattern, skin, hair colour and volume (0.5 cm to ``max_hair`` metres) and the
    wrinkles' seed of a :class:`SubjectSpec`, drawn in this order."""
    hue = rng.uniform(0, 1, 2)
    return {
        "top_colour": _colour(hue[0], rng),
        "bottom_colour": _colour(hue[1], rng),
        "pattern": str(rng.choice(["solid", "solid", "stripes", "checks"])),
        "skin": SKIN_TONES[rng.integers(len(SKIN_TONES))] * rng.uniform(0.95, 1.05, 3),
        "hair_colour": HAIR_COLOURS[rng.integers(len(HAIR_COLOURS))],
        "hair_volume": float(rng.uniform(0.005, max_hair)),
        "wrinkle_seed": int(rng.integers(2**31)),
    }


WIDE_HEIGHTS = (1.50, 1.95)
"""Body heights (metres, the unclothed canonical mesh) of the wide distribution."""
_WIDE_TRIES = 400  # draws of a wide body before giving up


def sample_wide_subject(rng: np.random.Generator, body: BodyModel,
                        clothing: str | None = None) -> SubjectSpec:  # fmt: skip
    """A subject of the harder distribution of suite v2: phenotypes across more of Anny's
    range, stronger and denser local changes, the whole body redrawn until its height lies in
    :data:`WIDE_HEIGHTS` and its proportions in the adult ranges
    (:func:`~monoavatar.synth.anthropometry.plausible`); garments 6–25 mm thick (tight ones
    4–8 mm) with deeper wrinkles and lengths varied, hair 0.5–3 cm thick in one of
    :data:`HAIR_STYLES`, shoes 6–20 mm."""
    if clothing is None:
        clothing = str(rng.choice(CLOTHING))
    if clothing not in CLOTHING:
        raise ValueError(f"unknown clothing {clothing!r}; choose from {CLOTHING}")
    for _ in range(_WIDE_TRIES):
        shape = np.zeros(body.shape_dim)
        shape[:6] = rng.uniform(-0.5, 0.5, 6)  # gender, age, muscle, weight, height, proportions
        shape[0] = rng.choice([-0.45, 0.45]) + rng.uniform(-0.05, 0.05)
        shape[1] = rng.uniform(-0.1, 0.35)  # adults
        if body.shape_dim > 6:  # local changes: denser and stronger than the standard ones
            active = rng.random(body.shape_dim - 6) < 0.4
            shape[6:] = active * rng.uniform(-0.9, 0.9, body.shape_dim - 6)
            shape[6:] = _nearly_symmetric(shape[6:], body, rng)
        stature, proportions = measure_body(body, shape)
        if WIDE_HEIGHTS[0] <= stature <= WIDE_HEIGHTS[1] and plausible(proportions):
            break
    else:
        raise RuntimeError(f"no wide subject of plausible proportions in {_WIDE_TRIES} draws")
    sleeve, leg = (float(np.clip(x + rng.uniform(-0.08, 0.08), 0.0, 1.0)) if x > 0.0 else 0.0
                   for x in _LENGTHS[clothing])  # fmt: skip
    if clothing == "minimal":
        top_t, bottom_t, wrinkle = 0.002, 0.002, 0.0005
    elif clothing == "tight":
        top_t, bottom_t, wrinkle = rng.uniform(0.004, 0.008, 2).tolist() + [0.0015]
    else:
        top_t, bottom_t = rng.uniform(0.006, 0.025, 2).tolist()
        wrinkle = float(rng.uniform(0.002, 0.008))
    return SubjectSpec(
        shape=shape,
        clothing=clothing,
        **_appearance(rng, 0.03),
        sleeve=sleeve,
        leg=leg,
        top_thickness=float(top_t),
        bottom_thickness=float(bottom_t),
        wrinkle_amplitude=float(wrinkle),
        skirt_flare=float(rng.uniform(0.08, 0.2)) if clothing == "skirt" else 0.0,
        hair_style=str(rng.choice(HAIR_STYLES)),
        shoe_height=float(rng.uniform(0.006, 0.02)),
    )


def _nearly_symmetric(local: np.ndarray, body: BodyModel, rng: np.random.Generator,
                      spread: float = 0.1) -> np.ndarray:  # fmt: skip
    """Local changes (L,) with each left/right pair (``l-…`` and ``r-…`` in the model's
    ``local_change_names``) made nearly equal, as people are: the right side takes the left
    side's value plus up to ±``spread`` (0 where the left one is off). Models without named
    local changes are returned as they are."""
    names = tuple(getattr(body, "local_change_names", ()))
    if len(names) != len(local):
        return local
    out = local.copy()
    index = {name: i for i, name in enumerate(names)}
    for i, name in enumerate(names):
        j = index.get("r-" + name[2:]) if name.startswith("l-") else None
        if j is not None:
            out[j] = local[i] + (rng.uniform(-spread, spread) if local[i] != 0 else 0.0)
    return out


def _hair(spec: SubjectSpec, p: np.ndarray, scalp: np.ndarray, region: dict[str, np.ndarray],
          head: np.ndarray, neck_y: float) -> np.ndarray:  # fmt: skip
    """(V_f,) hair thickness along the normals, metres, of style ``spec.hair_style`` (points
    ``p`` (V_f, 3) canonical, facing +Z; ``scalp`` the hair region as float; ``head`` the
    head joint (3,))."""
    hair = scalp * spec.hair_volume
    back = np.clip((head[2] - p[:, 2]) / 0.08, 0.0, 1.0)  # 0 in front of the head joint
    if spec.hair_style == "full":  # fuller at the top and the back
        top = np.clip((p[:, 1] - head[1]) / 0.1, 0.0, 1.0)
        hair = scalp * spec.hair_volume * (1.0 + 0.8 * np.maximum(top, back))
    elif spec.hair_style == "bun":  # a knot at the back of the head, above the head joint
        centre = head + np.array([0.0, 0.06, -0.09])
        d2 = ((p - centre) ** 2).sum(1)
        hair = hair + scalp * 0.045 * np.exp(-d2 / (2 * 0.035**2))
    elif spec.hair_style == "long":  # down the back of the head and the nape to the neck
        head_or_neck = region["torso"] | region["hair"] | region["face"]
        hang = (head_or_neck * back * _smoothstep(neck_y - 0.04, neck_y, p[:, 1])
                * (1 - _smoothstep(head[1] + 0.02, head[1] + 0.1, p[:, 1])))  # fmt: skip
        hair = np.maximum(hair, hang * (spec.hair_volume + 0.01))
    return hair


def _colour(hue: float, rng: np.random.Generator) -> np.ndarray:
    """A garment colour: any hue, moderate saturation and value (HSV → RGB)."""
    s, v = rng.uniform(0.2, 0.8), rng.uniform(0.25, 0.9)
    k = (np.array([5.0, 3.0, 1.0]) + hue * 6) % 6
    return v - v * s * np.clip(np.minimum(k, 4 - k), 0, 1)


def _smoothstep(edge0: float, edge1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - edge0) / (edge1 - edge0), 0.0, 1.0)
    return t * t * (3 - 2 * t)


def _along(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Fraction of the way from joint a to joint b of each point's projection."""
    ab = b - a
    return np.asarray(((p - a) @ ab) / (ab @ ab))


@dataclass
class Subject:
    """A built ground-truth subject.

    Attributes:
        spec: what was drawn.
        shape: (1, S) shape parameters (local-changes Anny).
        subdivision: the fine mesh's connectivity, UVs and skinning weights.
        rest_vertices: (V_f, 3) fine canonical vertices, clothing included, metres.
        displacement: (V_f,) clothing/hair displacement along canonical normals, metres.
        garment: (V_f,) index into :data:`GARMENTS` (0 skin, 1 top, 2 bottom, 3 hair, 4 shoes).
        texture: (T, T, 3) float albedo in [0, 1], glTF UVs.
        parts: (V_f,) dominant fitting joint of each fine vertex (for tests and labels).
    """

    spec: SubjectSpec
    shape: Tensor
    subdivision: Subdivision
    rest_vertices: Tensor
    displacement: np.ndarray
    garment: np.ndarray
    texture: np.ndarray
    parts: np.ndarray


def build_subject(body: BodyModel, spec: SubjectSpec, texture_size: int = 1024) -> Subject:
    """Build the fine, clothed, textured canonical mesh of ``spec`` on ``body``."""
    shape = torch.as_tensor(spec.shape, dtype=body.dtype)[None]
    with torch.no_grad():
        rest, joints = body.rest_shape(shape)
        sub = subdivide(body.faces, body.uv, body.face_uv, body.skin_weights)
        fine = sub.apply(rest)
        normals = vertex_normals(fine, sub.faces)[0].double().numpy()
    p = fine[0].double().numpy()
    J = joints[0].double().numpy()
    j = body.joint_index
    coarse_regions = body.regions.numpy()
    edges = sub.edges.numpy()
    regions = np.concatenate([coarse_regions, coarse_regions[edges[:, 0]]])
    region = {name: regions == i for i, name in enumerate(REGIONS)}

    waist_y = J[j("spine1"), 1] + 0.02
    neck_y = J[j("neck"), 1]
    top = np.zeros(len(p))
    bottom = np.zeros(len(p))
    torso_like = region["torso"] | region["arms"] | region["legs"]
    # top: torso between waist and neck, and the sleeves
    top += (
        torso_like
        * _smoothstep(waist_y - 0.06, waist_y - 0.03, p[:, 1])
        * (1 - _smoothstep(neck_y - 0.05, neck_y - 0.01, p[:, 1]))
    )
    for s in ("l", "r"):
        t = _along(p, J[j(f"shoulder_{s}")], J[j(f"wrist_{s}")])
        arm = region["arms"] & (t > -0.2)
        top = np.where(
            arm, (1 - _smoothstep(spec.sleeve - 0.03, spec.sleeve, t)) * (spec.sleeve > 0), top
        )
    # bottom: hips below the waist, and the legs down to the hem
    hips = torso_like & (p[:, 1] < waist_y)
    bottom += hips * (1 - _smoothstep(waist_y - 0.03, waist_y, p[:, 1]))
    for s in ("l", "r"):
        t = _along(p, J[j(f"hip_{s}")], J[j(f"ankle_{s}")])
        leg = region["legs"] & (t > 0.0)
        bottom = np.where(leg, (1 - _smoothstep(spec.leg - 0.03, spec.leg, t)), bottom)
    top = np.clip(top, 0, 1) * (spec.top_thickness > 0)
    bottom = np.clip(bottom, 0, 1) * (spec.bottom_thickness > 0)

    wr = np.random.default_rng(spec.wrinkle_seed)
    wrinkles = np.zeros(len(p))
    for _ in range(6):
        d = wr.normal(size=3)
        d /= np.linalg.norm(d)
        wrinkles += np.sin(wr.uniform(25, 70) * (p @ d) + wr.uniform(0, 2 * np.pi))
    wrinkles *= spec.wrinkle_amplitude / np.sqrt(6)

    disp = top * (spec.top_thickness + wrinkles) + bottom * (spec.bottom_thickness + wrinkles)
    if spec.skirt_flare > 0:
        below = np.clip(waist_y - 0.05 - p[:, 1], 0, None)
        disp += bottom * spec.skirt_flare * below / 0.5
    scalp = region["hair"].astype(float)
    hair = _hair(spec, p, scalp, region, J[j("head")], neck_y)
    disp += hair
    shoes = region["feet"].astype(float)
    disp += shoes * spec.shoe_height
    disp = np.maximum(disp, 0.0)

    garment = np.zeros(len(p), dtype=np.int64)
    garment[top > 0.5] = 1
    garment[bottom > 0.5] = 2
    garment[(scalp > 0.5) | (hair > 0.5 * spec.hair_volume)] = 3
    garment[shoes > 0.5] = 4
    rest_vertices = torch.as_tensor(p + disp[:, None] * normals, dtype=body.dtype)
    parts = sub.weights.argmax(dim=1).numpy()
    texture = paint_texture(spec, sub, p, garment, body, texture_size)
    return Subject(
        spec=spec,
        shape=shape,
        subdivision=sub,
        rest_vertices=rest_vertices,
        displacement=disp,
        garment=garment,
        texture=texture,
        parts=parts,
    )


def paint_texture(
    spec: SubjectSpec,
    sub: Subdivision,
    positions: np.ndarray,
    garment: np.ndarray,
    body: BodyModel,
    size: int,
) -> np.ndarray:
    """A procedural albedo texture (size, size, 3) in glTF UV layout: skin, face features, hair,
    garments with a pattern in canonical 3D coordinates, shoes; seams dilated."""
    import cv2

    uv = sub.uv.double().numpy()
    uv_points = np.concatenate([uv * size, np.ones((len(uv), 1))], axis=1)
    cam = PinholeCamera(K=np.eye(3), R=np.eye(3), t=np.zeros(3), width=size, height=size)
    frags = rasterize(uv_points, sub.face_uv, cam)
    face = frags.face_id.numpy()
    covered = face >= 0
    bary = frags.bary.numpy()[covered]
    f = sub.faces.numpy()[face[covered]]
    p = np.einsum("nk,nkc->nc", bary, positions[f])
    g = garment[f[np.arange(len(f)), bary.argmax(1)]]
    rng = np.random.default_rng(spec.wrinkle_seed + 1)

    noise_small = 1 + 0.04 * np.sin(180 * p[:, 0] + 3) * np.sin(170 * p[:, 1]) * np.sin(
        160 * p[:, 2]
    )
    colour = np.tile(spec.skin, (len(p), 1)) * noise_small[:, None]
    # face features where the subject's own face landmarks are
    with torch.no_grad():
        shape = torch.as_tensor(spec.shape, dtype=body.dtype)[None]
        kp = body.keypoints(body.rest_shape(shape)[0])[0].double().numpy()
    from monoavatar.body import MEDIAPIPE_LANDMARKS as L

    def near(name: str, radius: float, scale: tuple[float, float, float] = (1, 1, 1)) -> np.ndarray:
        c = kp[L.index(name)]
        d = (p - c) / np.array(scale)
        return np.asarray(np.linalg.norm(d, axis=1) < radius)

    lips = near("mouth_left", 0.03, (1.0, 0.35, 1.0)) | near("mouth_right", 0.03, (1.0, 0.35, 1.0))
    mouth_c = 0.5 * (kp[L.index("mouth_left")] + kp[L.index("mouth_right")])
    lips |= np.linalg.norm((p - mouth_c) / np.array([1.0, 0.35, 1.0]), axis=1) < 0.028
    colour[lips] = spec.skin * np.array([0.85, 0.55, 0.55])
    for side in ("left", "right"):
        eye = kp[L.index(f"{side}_eye")]
        d = np.linalg.norm((p - eye) / np.array([1.0, 0.6, 1.0]), axis=1)
        colour[d < 0.013] = [0.92, 0.92, 0.9]
        colour[d < 0.006] = [0.25, 0.18, 0.12]
        brow = np.linalg.norm(
            (p - eye - np.array([0, 0.022, 0])) / np.array([1.0, 0.25, 1.0]), axis=1
        )
        colour[brow < 0.016] = spec.hair_colour
    # garments
    pattern = np.ones(len(p))
    if spec.pattern == "stripes":
        pattern = np.where(np.sin(p[:, 1] * 2 * np.pi / 0.06) > 0, 1.0, 0.55)
    elif spec.pattern == "checks":
        pattern = np.where((np.floor(p[:, 0] / 0.05) + np.floor(p[:, 1] / 0.05)) % 2 == 0, 1.0, 0.6)
    fabric = 1 + 0.06 * rng.standard_normal(len(p)) * 0.3
    colour[g == 1] = spec.top_colour * (pattern * fabric)[g == 1, None]
    colour[g == 2] = spec.bottom_colour * fabric[g == 2, None]
    strands = 1 + 0.15 * np.sin(400 * p[:, 0] + 40 * np.sin(60 * p[:, 1]))
    colour[g == 3] = spec.hair_colour * strands[g == 3, None]
    colour[g == 4] = np.array([0.12, 0.11, 0.1]) * fabric[g == 4, None]

    image = np.zeros((size, size, 3), dtype=np.float32)
    image[covered] = np.clip(colour, 0, 1)
    # fill texels outside the UV islands from their neighbours so bilinear lookups at seams
    # do not bleed black
    filled = covered.copy()
    kernel = np.ones((3, 3), np.uint8)
    for _ in range(8):
        grown = cv2.dilate(image, kernel)
        count = cv2.dilate(filled.astype(np.uint8), kernel).astype(bool)
        new = count & ~filled
        image[new] = grown[new]
        filled |= new
    return image
