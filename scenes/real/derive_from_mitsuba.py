#!/usr/bin/env python3
"""Writes scenes/real/<name>.json from ../shared/scenes/<name>/source-scene.xml (Mitsuba 0.6).

Every number that describes the original scene comes from the XML; the rules are stated in
each file's "notes" and in docs/scene-format.md ("Real scenes"):
  camera    sensor toWorld (matrix: columns 1, 2, 3 = up, forward, origin; or lookat), fov with
            fovAxis (Mitsuba's default axis is x) converted to a vertical fov for the film's
            width/height; nearClip/farClip (Mitsuba defaults 0.01 / 10000 when absent).
  area      a rectangle emitter ([-1,1]^2 under toWorld): area A = 4 |col0| |col1|, centre =
            column 3 -> sphere light of radius sqrt(A / pi) and intensity L * A (the on-axis
            radiant intensity of a one-sided Lambertian emitter of radiance L).
  sphere    a sphere emitter of radius r and radiance L -> sphere light of radius r and
            intensity L * pi r^2.
  sunsky    sun -> distant light towards sunDirection, angular radius 0.2665 deg x
            sunRadiusScale, irradiance 2.5 x sunScale / 10; sky -> ambient 0.025 x skyScale.
  envmap    -> ambient (the EXR is not shipped, so only a uniform term can be derived).
  background: a light sky colour where the XML has a sky (sunsky, envmap), else black.
The camera path starts at the original camera and moves by small fractions of the model's
bounding box so that it stays inside the room (checked by looking at rendered frames).
Usage: scenes/real/derive_from_mitsuba.py [SHARED_SCENES_DIR]
"""
import json
import math
import os
import sys
import xml.etree.ElementTree as ET

HERE = os.path.dirname(os.path.abspath(__file__))
SHARED = sys.argv[1] if len(sys.argv) > 1 else os.path.join(HERE, "..", "..", "..", "shared", "scenes")

# Per scene: light exposure factor (1 = the physical conversion above), AO radius and the
# camera path as offsets (right, up, forward in metres; yaw and pitch of the view in degrees)
# from the original camera at t = 0, 4, 8, 12 s.
SETTINGS = {
    "living-room": {"exposure": 1.0, "ao_m": 0.5,
                    "path": [(0, 0, 0, 0, 0), (-0.6, 0.1, 0.8, 20, -3), (0.6, 0.2, 1.4, -25, -5), (0.2, 0.0, 0.3, 5, 0)]},
    "dining-room": {"exposure": 1.0, "ao_m": 0.5,
                    "path": [(0, 0, 0, 0, 0), (-0.8, -0.3, 1.2, 25, 0), (0.8, -0.5, 2.0, -30, -5), (0.3, 0.0, 0.5, -5, 0)]},
    "classroom": {"exposure": 1.0, "ao_m": 0.5,
                  "path": [(0, 0, 0, 0, 0), (0.6, 0.1, 1.0, -20, -5), (-0.6, 0.3, 1.8, 25, -8), (0.0, 0.0, 0.6, 0, 0)]},
    "staircase": {"exposure": 1.0, "ao_m": 0.4,
                  "path": [(0, 0, 0, 0, 0), (0.2, 0.3, 0.6, -10, 8), (-0.2, 0.6, 1.0, 12, 15), (0.0, 0.2, 0.3, 0, 4)]},
    "sponza-dabrovic": {"exposure": 1.0, "ao_m": 1.0,
                        "path": [(0, 0, 0, 0, 0), (0, -1.0, 3.0, -25, -5), (0, -2.0, 6.0, 25, -10), (0, -1.0, 2.0, 0, -3)]},
}


def floats(s):
    return [float(x) for x in s.replace(",", " ").split()]


def matrix(el):
    m = el.find("matrix")
    if m is not None:
        v = floats(m.get("value"))
        return [v[0:4], v[4:8], v[8:12], v[12:16]]
    la = el.find("lookat")
    if la is not None:
        o, t, u = floats(la.get("origin")), floats(la.get("target")), floats(la.get("up"))
        f = norm(sub(t, o))
        return {"lookat": (o, t, u, f)}
    raise SystemExit("unsupported transform")


def sub(a, b): return [a[i] - b[i] for i in range(3)]
def add(a, b): return [a[i] + b[i] for i in range(3)]
def mul(a, s): return [x * s for x in a]
def dot(a, b): return sum(a[i] * b[i] for i in range(3))
def cross(a, b): return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
def length(a): return math.sqrt(dot(a, a))
def norm(a): return mul(a, 1.0 / length(a))
def col(m, j): return [m[0][j], m[1][j], m[2][j]]
def r4(v): return [round(x, 4) for x in v]


def named(el, tag, name):
    for c in el.findall(tag):
        if c.get("name") == name:
            return c
    return None


def rgb_value(em):
    for tag in ("rgb", "spectrum"):
        c = named(em, tag, "radiance")
        if c is not None:
            v = floats(c.get("value"))
            return v if len(v) == 3 else [v[0]] * 3
    raise SystemExit("emitter without radiance")


def bbox(obj):
    lo, hi = [1e30] * 3, [-1e30] * 3
    with open(obj) as f:
        for line in f:
            if line.startswith("v "):
                p = [float(x) for x in line.split()[1:4]]
                lo = [min(lo[i], p[i]) for i in range(3)]
                hi = [max(hi[i], p[i]) for i in range(3)]
    return lo, hi


def derive(name):
    folder = os.path.join(SHARED, name)
    root = ET.parse(os.path.join(folder, "source-scene.xml")).getroot()
    cfg = SETTINGS[name]
    notes = []
    # --- camera
    sensor = root.find("sensor")
    fov = float(named(sensor, "float", "fov").get("value"))
    axis_el = named(sensor, "string", "fovAxis")
    axis = axis_el.get("value") if axis_el is not None else "x"
    film = sensor.find("film")
    w = int(named(film, "integer", "width").get("value"))
    h = int(named(film, "integer", "height").get("value"))
    if axis == "x":
        vfov = math.degrees(2 * math.atan(math.tan(math.radians(fov / 2)) * h / w))
    elif axis == "y":
        vfov = fov
    else:
        raise SystemExit(f"{name}: fovAxis {axis} not handled")
    near_el, far_el = named(sensor, "float", "nearClip"), named(sensor, "float", "farClip")
    near = float(near_el.get("value")) if near_el is not None else 0.01
    far = float(far_el.get("value")) if far_el is not None else 10000.0
    tw = matrix(sensor.find("transform"))
    if isinstance(tw, dict):
        origin, target, up_hint, fwd = tw["lookat"]
        right = norm(cross(fwd, up_hint))
        up = norm(cross(right, fwd))
        notes.append(f"camera: sensor lookat origin {r4(origin)} target {r4(target)} up {r4(up_hint)}")
    else:
        origin, fwd, up = col(tw, 3), norm(col(tw, 2)), norm(col(tw, 1))
        right = norm(cross(fwd, up))
        notes.append(f"camera: sensor toWorld matrix columns: origin {r4(origin)}, forward {r4(fwd)}, up {r4(up)}")
    notes.append(f"vfov: fov {fov} deg about axis {axis} on a {w}x{h} film -> vertical {vfov:.3f} deg; near/far {near}/{far}")
    keys = []
    for i, (dx, dy, dz, yaw, pitch) in enumerate(cfg["path"]):
        pos = add(origin, add(mul(right, dx), add(mul(up, dy), mul(fwd, dz))))
        yr, pr = math.radians(yaw), math.radians(pitch)
        # yaw about the camera's up (positive = to the left), then pitch.
        d = add(mul(fwd, math.cos(yr)), mul(right, -math.sin(yr)))
        d = norm(add(mul(d, math.cos(pr)), mul(up, math.sin(pr))))
        keys.append({"t_s": 4.0 * i, "position": r4(pos), "target": r4(add(pos, mul(d, 2.0)))})
    camera = {"vfov_deg": round(vfov, 3), "near_m": near, "far_m": far, "up": r4(up), "path": {"loop": False, "keys": keys}}
    # --- emitters
    lights, ambient, background = [], None, [0.0, 0.0, 0.0]
    exposure = cfg["exposure"]
    for em in root.iter("emitter"):
        t = em.get("type")
        if t == "sunsky":
            sd = norm(floats_vec(named(em, "vector", "sunDirection")))
            sun_scale = float(named(em, "float", "sunScale").get("value")) if named(em, "float", "sunScale") is not None else 1.0
            sky_scale = float(named(em, "float", "skyScale").get("value")) if named(em, "float", "skyScale") is not None else 1.0
            rs = named(em, "float", "sunRadiusScale")
            radius_scale = float(rs.get("value")) if rs is not None else 1.0
            lights.append({"type": "distant", "name": "sun", "direction": r4(sd), "angular_radius_deg": round(0.2665 * radius_scale, 4),
                           "colour": [1.0, 0.95, 0.88], "intensity": round(2.5 * sun_scale / 10 * exposure, 4)})
            ambient = {"colour": [0.75, 0.85, 1.0], "intensity": round(0.025 * sky_scale * exposure, 4)}
            background = [0.55, 0.7, 0.95]
            notes.append(f"sunsky: sunDirection {r4(sd)}, sunRadiusScale {radius_scale} -> angular radius 0.2665 x {radius_scale}; "
                         f"sunScale {sun_scale} -> sun irradiance 2.5 x {sun_scale}/10; skyScale {sky_scale} -> ambient 0.025 x {sky_scale}")
        elif t == "envmap":
            ambient = {"colour": [0.9, 0.95, 1.0], "intensity": round(0.6 * exposure, 4)}
            background = [0.55, 0.7, 0.95]
            notes.append("envmap (its EXR is not shipped): a uniform ambient term of 0.6; no direct light, so this scene has no shadow pass")
    for shape in root.iter("shape"):
        em = shape.find("emitter")
        if em is None or em.get("type") != "area":
            continue
        L = rgb_value(em)
        lum = max(L)
        colour = [round(c / lum, 4) for c in L]
        if shape.get("type") == "rectangle":
            m = matrix(shape.find("transform"))
            a = 4 * length(col(m, 0)) * length(col(m, 1))
            radius = math.sqrt(a / math.pi)
            lights.append({"type": "sphere", "name": f"area_rectangle_{len(lights)}", "position": r4(col(m, 3)),
                           "radius_m": round(radius, 4), "colour": colour, "intensity": round(lum * a * exposure, 3)})
            notes.append(f"area rectangle: centre {r4(col(m, 3))}, area {a:.4f} m^2 -> radius sqrt(A/pi) = {radius:.4f}; radiance {lum} x area -> intensity {lum * a:.3f}")
        elif shape.get("type") == "sphere":
            c = named(shape, "point", "center")
            centre = [float(c.get(k)) for k in "xyz"]
            r = float(named(shape, "float", "radius").get("value"))
            lights.append({"type": "sphere", "name": f"area_sphere_{len(lights)}", "position": r4(centre),
                           "radius_m": r, "colour": colour, "intensity": round(lum * math.pi * r * r * exposure, 3)})
            notes.append(f"area sphere: centre {r4(centre)}, radius {r}; radiance {lum} x pi r^2 -> intensity {lum * math.pi * r * r:.3f}")
        else:
            raise SystemExit(f"{name}: emitter shape {shape.get('type')} not handled")
    if ambient is None:
        ambient = {"colour": [1.0, 1.0, 1.0], "intensity": 0.05}
        notes.append("no sky or envmap in the XML: a small ambient term of 0.05 stands in for indirect light")
    lo, hi = bbox(os.path.join(folder, f"{name}.obj"))
    notes.append(f"model bounding box {r4(lo)} .. {r4(hi)}; camera path: the original camera at t = 0, then small moves and turns; AO radius {cfg['ao_m']} m")
    scene = {
        "version": 1,
        "name": name,
        "notes": f"Derived from ../shared/scenes/{name}/source-scene.xml by scenes/real/derive_from_mitsuba.py. " + "; ".join(notes) + ".",
        "geometry": [{"type": "mesh", "name": name, "file": f"{name}/{name}.obj"}],
        "lights": lights,
        "ambient": ambient,
        "ao": {"radius_m": cfg["ao_m"], "rays": 8},
        "background": background,
        "camera": camera,
    }
    sys.path.insert(0, HERE)
    with open(os.path.join(HERE, f"{name}.json"), "w") as f:
        f.write(format_json(scene) + "\n")


def floats_vec(el):
    return [float(el.get(k)) for k in "xyz"]


def format_json(o, ind=0):
    one = json.dumps(o, separators=(", ", ": "))
    if len(one) + ind <= 120 or not isinstance(o, (dict, list)):
        return one
    pad = " " * (ind + 2)
    if isinstance(o, dict):
        return "{\n" + ",\n".join(f"{pad}{json.dumps(k)}: {format_json(v, ind + 2)}" for k, v in o.items()) + "\n" + " " * ind + "}"
    return "[\n" + ",\n".join(pad + format_json(v, ind + 2) for v in o) + "\n" + " " * ind + "]"


if __name__ == "__main__":
    for n in SETTINGS:
        derive(n)
        print("wrote", os.path.join(HERE, n + ".json"))
