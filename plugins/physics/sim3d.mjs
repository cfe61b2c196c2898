// Ground-truth rollout of a 3D visphy scene spec with cannon-es (run by cannon3d.py).
//
// Usage: node sim3d.mjs [path/to/cannon-es/dist/cannon-es.js] < input.json > output.json
// (the library path may also come from $VISPHY_CANNON_ES). Input: {"spec": <visphy-scene/1 3d>,
// "masses": [kg per body, 0 for static], "n_steps": S}. Output (one JSON object on stdout):
//   body_ids, n_steps, step_poses (base64 float64 LE, (S+1)×B×7: x y z qx qy qz qw),
//   step_velocities (base64 float64 LE, (S+1)×B×6: vx vy vz wx wy wz), step_touching (base64
//   uint8, (S+1)×B), events, pair_stats, initial_penetration_m.
//
// The world follows the spec literally: fixed world.step(dt) (no substeps), no sleeping, naive
// broadphase, GSSolver with the spec's iterations, a static plane at y = floor.y, and one
// ContactMaterial for every pair of bodies (floor included) with the spec's explicit values, so
// cannon's product mixing rule is never used. State s is the state after s steps. The contacts
// of state s are found by the narrowphase of step s + 1, so one extra step is run (and not
// recorded) to know the contacts of the last state. Everything is deterministic: same input,
// same bytes.
import { pathToFileURL } from 'node:url';
import { readFileSync } from 'node:fs';

const libPath = process.argv[2] || process.env.VISPHY_CANNON_ES;
if (!libPath) {
  process.stderr.write('sim3d.mjs: give the path of cannon-es.js as argument or $VISPHY_CANNON_ES\n');
  process.exit(2);
}
const C = await import(pathToFileURL(libPath).href);
const input = JSON.parse(readFileSync(0, 'utf8'));
const spec = input.spec;
const W = spec.world;
const dt = W.dt_s;
const nSteps = input.n_steps;
const FLOOR = 'floor';
const SLIDE_SPEED = 0.05;

const world = new C.World({
  gravity: new C.Vec3(W.gravity_m_s2[0], W.gravity_m_s2[1], W.gravity_m_s2[2]),
  allowSleep: false,
  quatNormalizeSkip: W.quat_normalize ? W.quat_normalize.skip : 0,
  quatNormalizeFast: W.quat_normalize ? W.quat_normalize.fast : false,
});
world.broadphase = new C.NaiveBroadphase();
const solver = new C.GSSolver();
solver.iterations = W.solver.iterations;
solver.tolerance = W.solver.tolerance;
world.solver = solver;

const ce = W.contact_equation, fe = W.friction_equation;
function contactOptions(m) {
  return {
    friction: m.friction, restitution: m.restitution,
    contactEquationStiffness: ce.stiffness, contactEquationRelaxation: ce.relaxation,
    frictionEquationStiffness: fe.stiffness, frictionEquationRelaxation: fe.relaxation,
  };
}
const defaultMat = spec.contacts.default;
world.defaultContactMaterial = new C.ContactMaterial(world.defaultMaterial, world.defaultMaterial,
                                                     contactOptions(defaultMat));

function v3(a) { return new C.Vec3(a[0], a[1], a[2]); }

function makeShape(s) {
  if (s.type === 'sphere') return new C.Sphere(s.radius_m);
  if (s.type === 'box') return new C.Box(new C.Vec3(s.size_m[0] / 2, s.size_m[1] / 2, s.size_m[2] / 2));
  if (s.type === 'wedge') {
    const L = s.length_m, H = s.height_m, hw = s.width_m / 2;
    const x0 = -L / 3, x1 = 2 * L / 3, y0 = -H / 3, y1 = 2 * H / 3;
    const vertices = [[x0, y0, -hw], [x1, y0, -hw], [x0, y1, -hw],
                      [x0, y0, hw], [x1, y0, hw], [x0, y1, hw]].map(v3);
    // Counter-clockwise seen from outside (same list as spec3d.WEDGE_FACES).
    const faces = [[3, 4, 5], [0, 2, 1], [0, 1, 4, 3], [0, 3, 5, 2], [1, 2, 5, 4]];
    return new C.ConvexPolyhedron({ vertices, faces });
  }
  throw new Error(`unknown primitive shape ${s.type}`);
}

// ---------------------------------------------------------------------------------- bodies
const ids = spec.bodies.map(b => b.id);
const B = ids.length;
const order = new Map();           // cannon body -> index (spec order; floor = B)
const names = [...ids, FLOOR];
const materials = [];

const floor = new C.Body({ mass: 0, type: C.Body.STATIC });
floor.addShape(new C.Plane());
floor.quaternion.setFromEuler(-Math.PI / 2, 0, 0);   // plane normal +z -> +y
floor.position.set(0, W.floor.y, 0);
floor.material = new C.Material(FLOOR);

const bodies = spec.bodies.map((b, i) => {
  const dynamic = b.dynamic;
  const body = new C.Body({
    mass: dynamic ? input.masses[i] : 0,
    type: dynamic ? C.Body.DYNAMIC : C.Body.STATIC,
    linearDamping: W.damping.linear,
    angularDamping: W.damping.angular,
    allowSleep: false,
  });
  // Shapes are added at the identity pose: cannon-es approximates the inertia by the AABB of
  // the body at the time a shape is added, so this makes it the local (body-frame) AABB.
  if (b.shape.type === 'compound') {
    for (const part of b.shape.parts) {
      const q = part.quat;
      body.addShape(makeShape(part.shape), v3(part.offset_m), new C.Quaternion(q[0], q[1], q[2], q[3]));
    }
  } else {
    body.addShape(makeShape(b.shape));
  }
  const p = b.pose.position_m, q = b.pose.quat;
  body.position.set(p[0], p[1], p[2]);
  body.quaternion.set(q[0], q[1], q[2], q[3]);
  for (const v of [body.previousPosition, body.interpolatedPosition, body.initPosition]) v.copy(body.position);
  for (const v of [body.previousQuaternion, body.interpolatedQuaternion, body.initQuaternion]) v.copy(body.quaternion);
  if (dynamic) {
    body.velocity.copy(v3(b.velocity.linear_m_s));
    body.angularVelocity.copy(v3(b.velocity.angular_rad_s));
    body.initVelocity.copy(body.velocity);
    body.initAngularVelocity.copy(body.angularVelocity);
  }
  body.aabbNeedsUpdate = true;
  body.updateInertiaWorld(true);
  body.material = new C.Material(b.id);
  return body;
});

world.addBody(floor);
bodies.forEach((body, i) => { world.addBody(body); order.set(body, i); });
order.set(floor, B);
const all = [...bodies, floor];
for (const body of all) materials.push(body.material);

// One ContactMaterial per unordered pair (explicit pair value, else the default).
const pairTable = new Map();
for (const p of spec.contacts.pairs) pairTable.set([p.a, p.b].sort().join('\u0000'), p);
for (let i = 0; i < all.length; i++) {
  for (let j = i + 1; j < all.length; j++) {
    const a = names[i], b = names[j];
    const m = pairTable.get([a, b].sort().join('\u0000')) || defaultMat;
    world.addContactMaterial(new C.ContactMaterial(materials[i], materials[j], contactOptions(m)));
  }
}

// ------------------------------------------------------------------------------- recording
const poses = new Float64Array((nSteps + 1) * B * 7);
const vels = new Float64Array((nSteps + 1) * B * 6);
const touching = new Uint8Array((nSteps + 1) * B);
const events = [];
const stats = new Map();          // "a|b" -> {steps_touching, steps_sliding, max_normal_speed_m_s}
const penetration = new Map();    // "a|b" -> deepest penetration (m) in the initial state
let state = 0;                    // state whose contacts the running narrowphase computes

function key(bi, bj) {
  const i = order.get(bi), j = order.get(bj);
  return i <= j ? `${names[i]}|${names[j]}` : `${names[j]}|${names[i]}`;
}
function stat(k) {
  let s = stats.get(k);
  if (!s) { s = { steps_touching: 0, steps_sliding: 0, max_normal_speed_m_s: 0 }; stats.set(k, s); }
  return s;
}
const tmpA = new C.Vec3(), tmpB = new C.Vec3(), rel = new C.Vec3();
function relativeVelocity(c, out) {      // velocity of bj's contact point minus bi's
  c.bi.angularVelocity.cross(c.ri, tmpA); tmpA.vadd(c.bi.velocity, tmpA);
  c.bj.angularVelocity.cross(c.rj, tmpB); tmpB.vadd(c.bj.velocity, tmpB);
  tmpB.vsub(tmpA, out);
  return out;
}

function record(s) {
  bodies.forEach((body, i) => {
    const o = (s * B + i) * 7, p = body.position, q = body.quaternion;
    poses[o] = p.x; poses[o + 1] = p.y; poses[o + 2] = p.z;
    poses[o + 3] = q.x; poses[o + 4] = q.y; poses[o + 5] = q.z; poses[o + 6] = q.w;
    const u = (s * B + i) * 6, v = body.velocity, w = body.angularVelocity;
    vels[u] = v.x; vels[u + 1] = v.y; vels[u + 2] = v.z;
    vels[u + 3] = w.x; vels[u + 4] = w.y; vels[u + 5] = w.z;
  });
}

// Contact begins: fired after the narrowphase and before the solver, so velocities are those of
// the state the contact appears in. Speed: largest approach speed over the pair's contact points.
world.addEventListener('beginContact', (e) => {
  const k = key(e.bodyA, e.bodyB);
  let speed = 0;
  for (const c of world.contacts) {
    if (!((c.bi === e.bodyA && c.bj === e.bodyB) || (c.bi === e.bodyB && c.bj === e.bodyA))) continue;
    speed = Math.max(speed, -relativeVelocity(c, rel).dot(c.ni));
  }
  const [a, b] = k.split('|');
  events.push({ step: state, type: 'contact_begin', a, b, normal_speed_m_s: speed });
  const s = stat(k);
  s.max_normal_speed_m_s = Math.max(s.max_normal_speed_m_s, speed);
});

// Before integration, positions are still those of `state`: measure initial interpenetration.
const pen = new C.Vec3();
world.addEventListener('preStep', () => {
  if (state !== 0) return;
  for (const c of world.contacts) {
    // cannon's gap g = n · (xj + rj - xi - ri) is negative when the shapes interpenetrate
    c.bj.position.vadd(c.rj, pen); pen.vsub(c.bi.position, pen); pen.vsub(c.ri, pen);
    const k = key(c.bi, c.bj);
    penetration.set(k, Math.max(penetration.get(k) ?? -Infinity, -pen.dot(c.ni)));
  }
});

// After integration: the contacts of `state` with the step's final velocities (the solver's own
// velocities still lack this step's gravity, which integration adds). A contact slides when the
// tangential relative speed at a contact point exceeds SLIDE_SPEED.
world.addEventListener('postStep', () => {
  const touched = new Set(), slid = new Set();
  for (const c of world.contacts) {
    const k = key(c.bi, c.bj);
    for (const body of [c.bi, c.bj]) {
      const i = order.get(body);
      if (i < B) touching[state * B + i] = 1;
    }
    touched.add(k);
    if (!slid.has(k)) {
      relativeVelocity(c, rel);
      const vn = rel.dot(c.ni);
      const tx = rel.x - vn * c.ni.x, ty = rel.y - vn * c.ni.y, tz = rel.z - vn * c.ni.z;
      if (Math.sqrt(tx * tx + ty * ty + tz * tz) > SLIDE_SPEED) slid.add(k);
    }
  }
  for (const k of touched) stat(k).steps_touching += 1;
  for (const k of slid) stat(k).steps_sliding += 1;
});

record(0);
for (let s = 1; s <= nSteps + 1; s++) {
  state = s - 1;
  world.step(dt);
  if (s <= nSteps) record(s);
}

function b64(typed) { return Buffer.from(typed.buffer, typed.byteOffset, typed.byteLength).toString('base64'); }
const sortedKeys = [...stats.keys()].sort((x, y) => {
  const [xa, xb] = x.split('|').map(n => names.indexOf(n));
  const [ya, yb] = y.split('|').map(n => names.indexOf(n));
  return xa - ya || xb - yb;
});
const out = {
  body_ids: ids,
  n_steps: nSteps,
  step_poses: b64(poses),
  step_velocities: b64(vels),
  step_touching: b64(touching),
  events,
  pair_stats: Object.fromEntries(sortedKeys.map(k => [k, stats.get(k)])),
  initial_penetration_m: Object.fromEntries([...penetration.entries()].sort()),
};
process.stdout.write(JSON.stringify(out));
