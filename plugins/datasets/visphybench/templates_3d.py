"""The 3D subset of the generated VisPhyBench: 12 templates, 30 scenes (ids ``NN_tmpl_VV``).

Like the paper's 3D subset (Three.js + Cannon): spheres rolling down ramps (wedges) into U-shaped
containers, boxes knocked off planks, sphere collisions, stacks toppling, a seesaw, compound
shapes falling, balls launched with an initial velocity. Every scene has a dynamic red sphere
``red_ball`` (the action ball, #f34f46); dynamic bodies are gray / green / blue, static scenery
brown / purple, U containers translucent. As in the published clips, one fixed camera (at
(7, 6.2, 8.2) looking at (0, 1.2, 0), 45° vertical field of view) looks at every scene over an
18 m square grey floor seen corner-on, under a white sky, anti-aliased, Lambert-shaded, without
cast shadows; 75 frames at 15 fps (4 cannon steps of 1/60 s per frame). Templates lay bodies
out in metres; `blocks3d.scene_3d` scales each layout by `blocks3d.LAYOUT_SCALE` (Froude
scaling: the same story, larger and slower) and slides it over the floor so the camera frames
it.

`Template.make(rng, variant)` is deterministic in its arguments: the variant picks the discrete
arrangement, the generator the continuous parameters (sizes, positions, speeds, materials).
Candidates are screened by `screening3d.validity_problems_3d` and described by
`screening3d.difficulty_features_3d`; the bodies, shapes and camera come from `blocks3d`.
"""
# size: the 3D template catalogue, one entry per template

from __future__ import annotations

import math

import numpy as np

from visphy_core.api.spec import IDENTITY_QUAT, validate_spec_3d
from visphy_plugins.datasets.visphybench.blocks3d import (
    GAP,
    QUAT_Y_PI,
    G,
    Template,
    Wedge,
    add_backstop,
    box_shape,
    camera,
    centre_layout,
    centred_compound,
    lr_sign,
    make_body,
    mat,
    on_floor,
    random_quat,
    red_ball,
    rot_y,
    rot_z,
    scene_3d,
    sphere_shape,
    u_container_shape,
    uni,
    wedge_shape,
)
from visphy_plugins.datasets.visphybench.screening3d import (  # noqa: F401 - re-exported
    difficulty_features_3d,
    validity_problems_3d,
)


# ------------------------------------------------------------------------------ templates
def _t01_ramp_to_container(rng: np.random.Generator, variant: int) -> dict:
    d = lr_sign(rng)
    table_h, table_l = uni(rng, 0.55, 0.8), uni(rng, 1.5, 1.8)
    table = make_body("purple_table", "purple", box_shape(table_l, table_h, 1.0),
                      [-d * table_l / 2, table_h / 2, 0.0], dynamic=False, **mat(rng, "static"))
    ramp = Wedge(uni(rng, 0.9, 1.2), uni(rng, 0.45, 0.7), 0.7, 0.0, table_h, d)
    r, u = uni(rng, 0.14, 0.2), uni(rng, 0.05, 0.2)
    ball = red_ball(rng, ramp.on_slope(u, r), r)
    # where the ball lands (flies off the toe at the table's edge)
    v, th = ramp.roll_speed(u), ramp.theta
    x0, y0 = d * r * math.sin(th), table_h + r * math.cos(th)
    t_wall, inner, wall_h = 0.06, uni(rng, 0.8, 1.0), uni(rng, 0.28, 0.38)
    y_land = t_wall + r
    a, b_, c = 0.5 * G, v * math.sin(th), y_land - y0
    t_fly = (-b_ + math.sqrt(b_ * b_ - 4 * a * c)) / (2 * a)
    x_land = x0 + d * v * math.cos(th) * t_fly
    cx = x_land + d * uni(rng, -0.1, 0.15)
    near_outer = cx - d * (inner / 2 + t_wall)
    if d * near_outer < 0.08:
        cx += d * (0.08 - d * near_outer)
    shape, cy = u_container_shape(inner, wall_h, 0.8, t_wall)
    container = make_body("gray_container", "gray", shape, [cx, cy + GAP, 0.0],
                          mass=uni(rng, 1.5, 3.0), **mat(rng))
    bodies = [ball, ramp.body("brown_ramp", "brown"), table, container]
    if variant == 2:
        rb = 0.12
        bodies.append(make_body("blue_ball", "blue", sphere_shape(rb),
                                [cx + d * (inner / 2 - rb - 0.03), t_wall + rb + 2 * GAP, 0.0],
                                mass=uni(rng, 0.3, 0.6), **mat(rng, "sphere")))
    elif variant == 1:
        s = uni(rng, 0.25, 0.32)
        bodies.append(make_body("green_box", "green", box_shape(s, s, s),
                                on_floor(box_shape(s, s, s), cx + d * (inner / 2 + 0.5), 0.0),
                                mass=uni(rng, 0.3, 0.8), **mat(rng)))
    centre_layout(bodies)
    return scene_3d(1, variant, "ramp_container",
                    "a red ball rolls down a ramp on a table, flies off the edge and drops into "
                    "a gray U-shaped container", bodies, camera(rng, bodies))


def _t02_ramp_hits_box(rng: np.random.Generator, variant: int) -> dict:
    d = lr_sign(rng)
    ramp = Wedge(uni(rng, 1.4, 1.9), uni(rng, 0.7, 1.0), 1.0, 0.0, 0.0, d)
    r, u = uni(rng, 0.16, 0.22), uni(rng, 0.05, 0.15)
    bodies = [red_ball(rng, ramp.on_slope(u, r), r), ramp.body("brown_ramp", "brown")]
    x = d * uni(rng, 0.9, 1.4)
    s = uni(rng, 0.3, 0.4)
    cube = box_shape(s, s, s)
    bodies.append(make_body("green_box", "green", cube, on_floor(cube, x, 0.0),
                            mass=uni(rng, 0.3, 0.8), **mat(rng)))
    if variant == 1:
        s2 = uni(rng, 0.22, 0.3)
        top = box_shape(s2, s2, s2)
        bodies.append(make_body("gray_box", "gray", top, [x, s + GAP + s2 / 2 + GAP, 0.0],
                                mass=uni(rng, 0.2, 0.5), **mat(rng)))
    elif variant == 2:
        rb = uni(rng, 0.15, 0.2)
        bodies.append(make_body("blue_ball", "blue", sphere_shape(rb),
                                [x + d * (s / 2 + rb + 0.3), rb + GAP, uni(rng, -0.15, 0.15)],
                                mass=uni(rng, 0.4, 1.0), **mat(rng, "sphere")))
        bar = box_shape(0.12, 0.25, 2.4)
        bodies.append(make_body("brown_bar", "brown", bar,
                                [x + d * (s / 2 + 2 * rb + 1.0), 0.125, 0.0], dynamic=False,
                                **mat(rng, "static")))
    if variant != 2:
        add_backstop(rng, bodies, d)
    centre_layout(bodies)
    return scene_3d(2, variant, "ramp_box",
                    "a red ball rolls down a ramp and knocks into a box on the floor",
                    bodies, camera(rng, bodies))


def _t03_plank_knockoff(rng: np.random.Generator, variant: int) -> dict:
    d = lr_sign(rng)
    h, lp = uni(rng, 0.7, 1.0), uni(rng, 3.0, 3.5)
    bodies = []
    for side, name in ((-1, "purple_pillar_left"), (1, "purple_pillar_right")):
        bodies.append(make_body(name, "purple", box_shape(0.3, h, 0.6),
                                [side * (lp / 2 - 0.35), h / 2, 0.0], dynamic=False,
                                **mat(rng, "static")))
    bodies.append(make_body("brown_plank", "brown", box_shape(lp, 0.1, 0.7), [0.0, h + 0.05, 0.0],
                            dynamic=False, **mat(rng, "static")))
    top = h + 0.1
    s = uni(rng, 0.26, 0.34)
    bx = d * (lp / 2 - s / 2 - uni(rng, 0.02, 0.12))
    cube = box_shape(s, s, s)
    bodies.append(make_body("green_box", "green", cube, [bx, top + s / 2 + GAP, 0.0],
                            mass=uni(rng, 0.2, 0.6), **mat(rng)))
    if variant == 1:
        s2 = uni(rng, 0.2, 0.26)
        bodies.append(make_body("gray_box", "gray", box_shape(s2, s2, s2),
                                [bx, top + s + 2 * GAP + s2 / 2 + GAP, 0.0],
                                mass=uni(rng, 0.1, 0.4), **mat(rng)))
    elif variant == 2:
        rb = uni(rng, 0.12, 0.16)
        bodies.append(make_body("blue_ball", "blue", sphere_shape(rb),
                                [uni(rng, -0.3, 0.3), top + rb + GAP, 0.0],
                                mass=uni(rng, 0.3, 0.8), **mat(rng, "sphere")))
    r = uni(rng, 0.15, 0.2)
    bodies.insert(0, red_ball(rng, [-d * (lp / 2 - 0.3), top + r + GAP, 0.0], r,
                              velocity=(d * uni(rng, 3.5, 5.0), 0.0, 0.0),
                              mass=uni(rng, 1.5, 3.0)))
    add_backstop(rng, bodies, d, height=0.8, distance=(1.1, 1.4))
    return scene_3d(3, variant, "plank_knockoff",
                    "a red ball rolls along a raised plank and knocks a box off its end",
                    bodies, camera(rng, bodies))


def _t04_sphere_collision(rng: np.random.Generator, variant: int) -> dict:
    d = lr_sign(rng)
    r = uni(rng, 0.2, 0.26)
    tx = d * uni(rng, 0.1, 0.6)
    targets = []
    n = variant + 1
    colors = ["blue", "green", "gray"]
    rt = uni(rng, 0.18, 0.24)
    if n == 1:
        spots = [(tx, uni(rng, -0.3, 0.3))]
    elif n == 2:
        z = uni(rng, -0.2, 0.2)
        spots = [(tx, z), (tx + d * (2 * rt + uni(rng, 0.3, 0.6)), z + uni(rng, -0.2, 0.2))]
    else:
        z = uni(rng, -0.15, 0.15)
        dx = rt * math.sqrt(3) + 0.02
        spots = [(tx, z), (tx + d * dx, z - rt - 0.01), (tx + d * dx, z + rt + 0.01)]
    for i, (x, z) in enumerate(spots):
        targets.append(make_body(f"{colors[i]}_ball", colors[i], sphere_shape(rt),
                                 [x, rt + GAP, z], mass=uni(rng, 0.5, 1.5), **mat(rng, "sphere")))
    x0, z0 = -d * uni(rng, 1.6, 2.0), uni(rng, -0.4, 0.4)
    vx = d * uni(rng, 3.5, 5.0)
    t_hit = abs(spots[0][0] - x0) / abs(vx)
    vz = (spots[0][1] + uni(rng, -0.08, 0.08) - z0) / t_hit
    bodies = [red_ball(rng, [x0, r + GAP, z0], r, velocity=(vx, 0.0, vz))] + targets
    bodies.append(make_body("brown_bumper", "brown", box_shape(0.15, 0.3, 3.0),
                            [d * 2.5, 0.15, 0.0], dynamic=False, **mat(rng, "static")))
    return scene_3d(4, variant, "sphere_collision",
                    "a red ball launched along the floor collides with other balls",
                    bodies, camera(rng, bodies))


def _t05_stack_topple(rng: np.random.Generator, variant: int) -> dict:
    d = lr_sign(rng)
    tx = d * uni(rng, 0.6, 1.1)
    n = 4 if variant == 1 else 3
    colors = ["gray", "green", "blue", "gray"]
    bodies, y = [], 0.0
    sizes = sorted((uni(rng, 0.3, 0.42) for _ in range(n)), reverse=True)
    for i, s in enumerate(sizes):
        y += GAP
        q = rot_y(uni(rng, -0.15, 0.15))
        bodies.append(make_body(f"{colors[i]}_box_{i}", colors[i], box_shape(s, s, s),
                                [tx + uni(rng, -0.02, 0.02), y + s / 2, uni(rng, -0.02, 0.02)], q,
                                mass=uni(rng, 0.3, 0.8), **mat(rng)))
        y += s
    r = uni(rng, 0.17, 0.22)
    if variant == 0:  # a big fast ball rolling along the floor
        r = uni(rng, 0.26, 0.3)
        x0 = -d * uni(rng, 2.0, 2.5)
        ball = red_ball(rng, [x0, r + GAP, 0.0], r, velocity=(d * uni(rng, 5.5, 7.0), 0.0, 0.0),
                        mass=uni(rng, 2.0, 3.0))
    elif variant == 1:
        x0, y0 = -d * uni(rng, 2.2, 2.6), uni(rng, 0.4, 0.8)
        t = uni(rng, 0.5, 0.7)
        ty = y - sizes[-1] / 2
        ball = red_ball(rng, [x0, y0, 0.0], r,
                        velocity=((tx - x0) / t, (ty - y0 + 0.5 * G * t * t) / t, 0.0))
    else:
        ramp = Wedge(uni(rng, 1.2, 1.5), uni(rng, 0.6, 0.8), 0.9,
                     tx - d * uni(rng, 0.9, 1.2), 0.0, d)
        ball = red_ball(rng, ramp.on_slope(uni(rng, 0.05, 0.15), r), r)
        bodies.append(ramp.body("brown_ramp", "brown"))
    # a wall as high as the stack stops the flying boxes (and a thrown ball) in view
    add_backstop(rng, bodies, d, height=y)
    bodies.insert(0, ball)
    centre_layout(bodies)
    return scene_3d(5, variant, "stack_topple",
                    "a red ball hits a stack of boxes and topples it", bodies, camera(rng, bodies))


def _t06_seesaw(rng: np.random.Generator, variant: int) -> dict:
    d = lr_sign(rng)
    hf, lw = uni(rng, 0.3, 0.4), 0.4
    fulcrum = make_body("purple_fulcrum", "purple", wedge_shape(lw, hf, 0.6),
                        [d * lw / 3, hf / 3, 0.0], IDENTITY_QUAT if d > 0 else QUAT_Y_PI,
                        dynamic=False, **mat(rng, "static"))
    lp, t = uni(rng, 2.6, 3.1), 0.08
    s_e = uni(rng, -0.15, 0.15)
    alpha = math.asin(hf / (s_e + lp / 2))
    u = np.array([d * math.cos(alpha), math.sin(alpha), 0.0])
    nrm = np.array([-d * math.sin(alpha), math.cos(alpha), 0.0])
    c = np.array([0.0, hf, 0.0]) + (t / 2 + GAP) * nrm - s_e * u
    q = rot_z(d * alpha)
    plank = make_body("blue_plank", "blue", box_shape(lp, t, 0.5), c, q,
                      mass=uni(rng, 1.0, 1.6), **mat(rng, "grippy"))
    sb = uni(rng, 0.24, 0.3)
    s_box = -(lp / 2 - sb / 2 - 0.08)
    box_c = c + s_box * u + (t / 2 + sb / 2 + GAP) * nrm
    bodies = [fulcrum, plank,
              make_body("green_box", "green", box_shape(sb, sb, sb), box_c, q,
                        mass=uni(rng, 0.2, 0.5), **mat(rng, "grippy"))]
    if variant == 1:
        s2 = uni(rng, 0.18, 0.22)
        top_c = box_c + (sb / 2 + s2 / 2 + GAP) * nrm
        bodies.append(make_body("gray_box", "gray", box_shape(s2, s2, s2), top_c, q,
                                mass=uni(rng, 0.1, 0.3), **mat(rng, "grippy")))
    r = uni(rng, 0.17, 0.22)
    s_ball = lp / 2 - uni(rng, 0.2, 0.4)
    p = c + s_ball * u
    height = uni(rng, 0.6, 1.2)
    vx = -d * uni(rng, 0.3, 0.8) if variant == 2 else 0.0
    bodies.insert(0, red_ball(rng, [p[0] - vx * 0.3, p[1] + height, 0.0], r,
                              velocity=(vx, 0.0, 0.0), mass=uni(rng, 1.5, 2.5)))
    add_backstop(rng, bodies, d, distance=(0.5, 0.7))
    add_backstop(rng, bodies, -d, name="brown_backstop_far", distance=(0.5, 0.7))
    centre_layout(bodies)
    return scene_3d(6, variant, "seesaw",
                    "a heavy red ball drops on the raised end of a plank balanced on a wedge "
                    "and catapults the box on the other end", bodies, camera(rng, bodies))


def _l_shape() -> dict:
    return centred_compound([(box_shape(0.6, 0.15, 0.3), [0.0, 0.0, 0.0]),
                              (box_shape(0.15, 0.45, 0.3), [-0.225, 0.3, 0.0])])[0]


def _t_shape() -> dict:
    return centred_compound([(box_shape(0.7, 0.12, 0.28), [0.0, 0.5, 0.0]),
                              (box_shape(0.14, 0.44, 0.28), [0.0, 0.22, 0.0])])[0]


def _dumbbell() -> dict:
    return centred_compound([(sphere_shape(0.15), [-0.35, 0.0, 0.0]),
                              (box_shape(0.4, 0.08, 0.08), [0.0, 0.0, 0.0]),
                              (sphere_shape(0.15), [0.35, 0.0, 0.0])])[0]


def _t07_compound_fall(rng: np.random.Generator, variant: int) -> dict:
    d = lr_sign(rng)
    bodies = []
    spin = lambda: tuple(uni(rng, -2.5, 2.5) for _ in range(3))  # noqa: E731
    if variant == 0:
        ramp = Wedge(uni(rng, 1.0, 1.3), uni(rng, 0.5, 0.7), 0.9, -d * 0.4, 0.0, d)
        bodies.append(ramp.body("brown_ramp", "brown"))
        bodies.append(make_body("green_l_shape", "green", _l_shape(),
                                [ramp.cx, uni(rng, 1.5, 2.0), uni(rng, -0.2, 0.2)],
                                random_quat(rng), angular=spin(), mass=uni(rng, 0.5, 1.2),
                                **mat(rng)))
        bodies.append(make_body("blue_dumbbell", "blue", _dumbbell(),
                                [d * uni(rng, 1.3, 1.7), uni(rng, 1.0, 1.6), uni(rng, -0.3, 0.3)],
                                random_quat(rng), angular=spin(), mass=uni(rng, 0.5, 1.2),
                                **mat(rng)))
        r = uni(rng, 0.16, 0.2)
        bodies.insert(0, red_ball(rng, [ramp.cx - d * 0.1, uni(rng, 0.9, 1.2), 0.0], r,
                                  velocity=(d * uni(rng, 0.5, 1.0), 0.0, 0.0)))
        add_backstop(rng, bodies, d)
    else:
        h, lp = uni(rng, 0.5, 0.7), uni(rng, 2.0, 2.4)
        for side, name in ((-1, "purple_pillar_left"), (1, "purple_pillar_right")):
            bodies.append(make_body(name, "purple", box_shape(0.25, h, 0.6),
                                    [side * (lp / 2 - 0.3), h / 2, 0.0], dynamic=False,
                                    **mat(rng, "static")))
        bodies.append(make_body("brown_plank", "brown", box_shape(lp, 0.1, 0.7),
                                [0.0, h + 0.05, 0.0], dynamic=False, **mat(rng, "static")))
        bodies.append(make_body("gray_t_shape", "gray", _t_shape(),
                                [d * uni(rng, 0.3, 0.6), h + uni(rng, 1.0, 1.5), 0.0],
                                random_quat(rng), angular=spin(), mass=uni(rng, 0.5, 1.2),
                                **mat(rng)))
        bodies.append(make_body("green_l_shape", "green", _l_shape(),
                                [-d * uni(rng, 1.8, 2.2), uni(rng, 0.8, 1.3), 0.0],
                                random_quat(rng), angular=spin(), mass=uni(rng, 0.5, 1.2),
                                **mat(rng)))
        r = uni(rng, 0.16, 0.2)
        bodies.insert(0, red_ball(rng, [-d * uni(rng, 0.3, 0.6), h + uni(rng, 0.7, 1.0), 0.0], r))
    centre_layout(bodies)
    return scene_3d(7, variant, "compound_fall",
                    "compound shapes and a red ball fall, bounce and tumble",
                    bodies, camera(rng, bodies))


def _t08_launch_into_container(rng: np.random.Generator, variant: int) -> dict:
    d = lr_sign(rng)
    inner, wall_h, t_wall = uni(rng, 0.8, 1.0), uni(rng, 0.3, 0.42), 0.06
    cx = d * uni(rng, 1.2, 1.8)
    shape, cy = u_container_shape(inner, wall_h, 0.8, t_wall)
    dynamic = variant == 1
    container = make_body("gray_container" if dynamic else "purple_container",
                          "gray" if dynamic else "purple", shape, [cx, cy + GAP, 0.0],
                          dynamic=dynamic, mass=uni(rng, 1.5, 3.0),
                          **mat(rng, "box" if dynamic else "static"))
    r = uni(rng, 0.15, 0.2)
    x0, y0 = -d * uni(rng, 2.2, 2.6), uni(rng, 0.3, 0.8)
    tx, ty = cx + d * uni(rng, -0.15, 0.15), t_wall + r
    t = uni(rng, 0.8, 1.0)
    ball = red_ball(rng, [x0, y0, 0.0], r,
                    velocity=((tx - x0) / t, (ty - y0 + 0.5 * G * t * t) / t, 0.0))
    plank = box_shape(1.0, 0.06, 0.2)
    bodies = [ball, container,
              make_body("blue_plank", "blue", plank,
                        on_floor(plank, cx - d * (inner / 2 + 0.75), uni(rng, -0.6, 0.6)),
                        rot_y(uni(rng, -0.6, 0.6)), mass=uni(rng, 0.2, 0.5), **mat(rng))]
    if dynamic:
        s = uni(rng, 0.2, 0.26)
        bodies.append(make_body("green_box", "green", box_shape(s, s, s),
                                [cx + d * (inner / 2 - s / 2 - 0.04), t_wall + s / 2 + 2 * GAP,
                                 0.0], mass=uni(rng, 0.2, 0.5), **mat(rng)))
    if dynamic:
        add_backstop(rng, bodies, d)
    return scene_3d(8, variant, "launch_container",
                    "a red ball is thrown in an arc into a U-shaped container",
                    bodies, camera(rng, bodies))


def _t09_dominoes(rng: np.random.Generator, variant: int) -> dict:
    d = lr_sign(rng)
    n = 5 if variant == 0 else 6
    h, gap = uni(rng, 0.6, 0.75), uni(rng, 0.32, 0.4)
    colors = ["gray", "green", "blue"]
    x_first = -d * (n - 1) * gap / 2 + d * 0.6
    bodies = []
    for i in range(n):
        plank = box_shape(0.07, h, 0.45)
        bodies.append(make_body(f"{colors[i % 3]}_domino_{i}", colors[i % 3], plank,
                                [x_first + d * i * gap, h / 2 + GAP, uni(rng, -0.03, 0.03)],
                                mass=uni(rng, 0.2, 0.4), **mat(rng, "grippy")))
    r = uni(rng, 0.14, 0.18)
    x0, y0 = x_first - d * uni(rng, 0.8, 1.0), uni(rng, 0.45, 0.55)
    bodies.insert(0, red_ball(rng, [x0, y0, 0.0], r,
                              velocity=(d * uni(rng, 3.0, 4.0), 0.0, 0.0)))
    centre_layout(bodies)
    return scene_3d(9, variant, "dominoes",
                    "a red ball thrown at a row of standing planks knocks them over like "
                    "dominoes", bodies, camera(rng, bodies))


def _t10_incline_slide(rng: np.random.Generator, variant: int) -> dict:
    d = lr_sign(rng)
    lp, t, beta = uni(rng, 2.2, 2.6), 0.08, math.radians(uni(rng, 20.0, 27.0))
    u = np.array([d * math.cos(beta), -math.sin(beta), 0.0])     # downhill
    nrm = np.array([d * math.sin(beta), math.cos(beta), 0.0])    # up, out of the plank
    c = np.array([0.0, lp / 2 * math.sin(beta) + t / 2 * math.cos(beta), 0.0])
    q = rot_z(-d * beta)
    s_sup = -(lp / 2 - 0.25)
    sup_x = c[0] + s_sup * u[0]
    # the support's top lies just under the plank's underside at its downhill edge
    under = c - (t / 2) * nrm
    x_edge = sup_x + d * 0.2
    sup_top = under[1] + (x_edge - under[0]) * (u[1] / u[0]) - 0.003
    bodies = [make_body("brown_plank", "brown", box_shape(lp, t, 0.9), c, q, dynamic=False,
                        **mat(rng, "static")),
              make_body("purple_support", "purple", box_shape(0.4, sup_top, 0.9),
                        [sup_x, sup_top / 2, 0.0], dynamic=False, **mat(rng, "static"))]
    sb = uni(rng, 0.24, 0.3)
    box_c = c - (lp / 2 - 0.45) * u + (t / 2 + sb / 2 + GAP) * nrm + np.array([0, 0, -0.2])
    green = make_body("green_box", "green", box_shape(sb, sb, sb), box_c, q,
                      mass=uni(rng, 0.3, 0.7), **mat(rng))
    green["material"]["friction"] = 0.0003
    r = uni(rng, 0.14, 0.18)
    ball_c = c - (lp / 2 - 0.4) * u + (t / 2 + r + GAP) * nrm + np.array([0, 0, 0.22])
    bodies.insert(0, red_ball(rng, ball_c, r))
    bodies.append(green)
    low_x = c[0] + lp / 2 * u[0]
    if variant == 0:
        rb = uni(rng, 0.16, 0.2)
        bodies.append(make_body("blue_ball", "blue", sphere_shape(rb),
                                [low_x + d * uni(rng, 0.5, 0.9), rb + GAP, uni(rng, -0.2, 0.2)],
                                mass=uni(rng, 0.4, 1.0), **mat(rng, "sphere")))
    else:
        s = uni(rng, 0.3, 0.38)
        cube = box_shape(s, s, s)
        bodies.append(make_body("gray_box", "gray", cube,
                                on_floor(cube, low_x + d * uni(rng, 0.6, 1.0), 0.0),
                                mass=uni(rng, 0.3, 0.8), **mat(rng)))
    add_backstop(rng, bodies, d)
    centre_layout(bodies)
    spec = scene_3d(10, variant, "incline_slide",
                    "a box slides and a red ball rolls down an inclined plank towards an object "
                    "on the floor", bodies, camera(rng, bodies))
    for pair in spec["contacts"]["pairs"]:  # a slippery box on the plank
        if {pair["a"], pair["b"]} == {"green_box", "brown_plank"}:
            pair["friction"] = 0.0003
    return spec


def _t11_bridge(rng: np.random.Generator, variant: int) -> dict:
    d = lr_sign(rng)
    hp, lp = uni(rng, 0.55, 0.7), uni(rng, 1.4, 1.7)
    xb = d * uni(rng, 0.6, 1.0)
    bodies = []
    for side, name in ((-1, "gray_pillar_a"), (1, "gray_pillar_b")):
        pillar = box_shape(0.22, hp, 0.4)
        bodies.append(make_body(name, "gray", pillar,
                                [xb + side * (lp / 2 - 0.2), hp / 2 + GAP, 0.0],
                                mass=uni(rng, 0.2, 0.4), **mat(rng, "grippy")))
    plank_y = hp + 2 * GAP + 0.04 + GAP
    bodies.append(make_body("blue_plank", "blue", box_shape(lp, 0.08, 0.5), [xb, plank_y, 0.0],
                            mass=uni(rng, 0.4, 0.8), **mat(rng)))
    s = uni(rng, 0.24, 0.3)
    bodies.append(make_body("green_box", "green", box_shape(s, s, s),
                            [xb + uni(rng, -0.2, 0.2), plank_y + 0.04 + s / 2 + GAP, 0.0],
                            mass=uni(rng, 0.2, 0.5), **mat(rng)))
    r = uni(rng, 0.17, 0.22)
    if variant == 0:
        x0 = -d * uni(rng, 2.0, 2.4)
        ball = red_ball(rng, [x0, r + GAP, 0.0], r, velocity=(d * uni(rng, 5.5, 7.0), 0.0, 0.0),
                        mass=uni(rng, 2.0, 3.0))
    else:
        ball = red_ball(rng, [xb - d * (lp / 2 - 0.15), plank_y + uni(rng, 1.2, 1.8), 0.0], r,
                        mass=uni(rng, 3.0, 5.0))
    if variant == 0:
        add_backstop(rng, bodies, d)
    bodies.insert(0, ball)
    centre_layout(bodies)
    return scene_3d(11, variant, "bridge_collapse",
                    "a red ball hits a plank bridge on two pillars and brings it down",
                    bodies, camera(rng, bodies))


def _t12_bowling(rng: np.random.Generator, variant: int) -> dict:
    d = lr_sign(rng)
    x_front = d * uni(rng, 0.5, 0.8)
    spacing = uni(rng, 0.32, 0.38)
    pin_h = uni(rng, 0.5, 0.6)
    bodies = []
    k = 0
    for row in range(3):
        for j in range(row + 1):
            z = (j - row / 2) * spacing
            x = x_front + d * row * spacing * 0.9
            color = "green" if (row + j) % 2 else "gray"
            if variant == 1 and row == 2:
                rb = 0.13
                bodies.append(make_body(f"blue_ball_{k}", "blue", sphere_shape(rb),
                                        [x, rb + GAP, z], mass=uni(rng, 0.2, 0.5),
                                        **mat(rng, "sphere")))
            else:
                pin = box_shape(0.16, pin_h, 0.16)
                bodies.append(make_body(f"{color}_pin_{k}", color, pin, [x, pin_h / 2 + GAP, z],
                                        mass=uni(rng, 0.15, 0.3), **mat(rng, "grippy")))
            k += 1
    bodies.append(make_body("brown_backstop", "brown", box_shape(0.12, 0.35, 2.2),
                            [x_front + d * uni(rng, 1.3, 1.5), 0.175, 0.0], dynamic=False,
                            **mat(rng, "static")))
    r = uni(rng, 0.2, 0.25)
    x0 = -d * uni(rng, 1.6, 2.0)
    z0 = uni(rng, -0.4, 0.4)
    vx = d * uni(rng, 5.0, 6.5)
    vz = (uni(rng, -0.1, 0.1) - z0) / (abs(x_front - x0) / abs(vx))
    bodies.insert(0, red_ball(rng, [x0, r + GAP, z0], r, velocity=(vx, 0.0, vz),
                              mass=uni(rng, 1.5, 3.0)))
    centre_layout(bodies)
    return scene_3d(12, variant, "bowling",
                    "a red ball rolls into a triangle of pins", bodies, camera(rng, bodies))


TEMPLATES_3D: list[Template] = [
    Template(1, "ramp_container", 3, "ball rolls down a ramp on a table into a U container",
             _t01_ramp_to_container),
    Template(2, "ramp_box", 3, "ball rolls down a ramp into boxes", _t02_ramp_hits_box),
    Template(3, "plank_knockoff", 3, "ball knocks a box off a raised plank", _t03_plank_knockoff),
    Template(4, "sphere_collision", 3, "ball launched into other balls", _t04_sphere_collision),
    Template(5, "stack_topple", 3, "ball topples a stack of boxes", _t05_stack_topple),
    Template(6, "seesaw", 3, "ball drops on a seesaw plank and launches a box", _t06_seesaw),
    Template(7, "compound_fall", 2, "compound shapes fall and tumble", _t07_compound_fall),
    Template(8, "launch_container", 2, "ball thrown into a U container",
             _t08_launch_into_container),
    Template(9, "dominoes", 2, "ball knocks over a row of standing planks", _t09_dominoes),
    Template(10, "incline_slide", 2, "box and ball slide/roll down an inclined plank",
             _t10_incline_slide),
    Template(11, "bridge_collapse", 2, "ball brings down a plank bridge", _t11_bridge),
    Template(12, "bowling", 2, "ball rolls into a triangle of pins", _t12_bowling),
]


def draw_seed_3d(template_id: int, variant: int, draw: int) -> int:
    """Seed of candidate `draw` of a slot in `generate_scene_3d` (variant 0: template_id·100 +
    draw). The benchmark builder uses its own seeds (`catalogue.scene_seed`)."""
    return template_id * 100 + variant * 10 + draw


def generate_scene_3d(template_id: int, variant: int = 0, max_draws: int = 4,
                      features: bool = True):
    """First valid candidate of a slot: (annotated spec, rollout, draws used).

    Fills ``seed``, ``ground_truth.events``, ``digest_sha256`` and the difficulty features
    (label left None: labels are relative to a whole benchmark). Raises RuntimeError with the
    rejection reasons when no draw is valid.
    """
    from visphy_plugins.physics.cannon import simulate_3d, trajectory_digest_3d

    template = next(t for t in TEMPLATES_3D if t.template_id == template_id)
    reasons: list[str] = []
    for k in range(max_draws):
        seed = draw_seed_3d(template_id, variant, k)
        spec = template.make(np.random.default_rng(seed), variant)
        spec["seed"] = seed
        validate_spec_3d(spec)
        rollout = simulate_3d(spec)
        problems = validity_problems_3d(spec, rollout)
        if problems:
            reasons.extend(problems)
            continue
        feats = difficulty_features_3d(spec, rollout) if features else {}
        spec["difficulty"] = {"label": None, "score": 0.0, "features": feats}
        spec["ground_truth"]["events"] = rollout.events
        spec["digest_sha256"] = trajectory_digest_3d(rollout)
        validate_spec_3d(spec)
        return spec, rollout, k + 1
    raise RuntimeError(f"3D template {template_id} variant {variant}: no valid candidate in "
                       f"{max_draws} draws (rejected: {reasons})")
