// visphy 2D constraint helper, inlined by the trusted template in the head of 2D pages.
// A 3D rigid-body engine used for a 2D scene keeps every moving body in the x-y plane: bodies
// start at z = 0, and around every fixed sub-step (World.prototype.internalStep; step() where a
// build has none) out-of-plane position and velocity are clamped to zero, as are the angular
// components that would tilt a body out of the plane (angular velocity and torque about x and y).
// The orientation is kept a rotation about z applied to the body's orientation when first seen,
// so a body whose shape was deliberately turned (a cylinder facing the camera) keeps that turn.
// Static bodies (ground planes rotated to face +y, walls) are left alone.
// Works for cannon.js 0.6.2 (global CANNON) and cannon-es (the /vendor/cannon-es.js wrapper).
(function () {
  'use strict';
  if (window.__visphyConstrain2D) return;
  const STATIC = 2;                 // Body.STATIC in cannon 0.6.2 and cannon-es
  const initial = new WeakMap();    // body -> its orientation [x, y, z, w] when first constrained
  const patched = new WeakSet();

  function mul(a, b) {              // quaternion product a * b, [x, y, z, w]
    return [
      a[3] * b[0] + a[0] * b[3] + a[1] * b[2] - a[2] * b[1],
      a[3] * b[1] - a[0] * b[2] + a[1] * b[3] + a[2] * b[0],
      a[3] * b[2] + a[0] * b[1] - a[1] * b[0] + a[2] * b[3],
      a[3] * b[3] - a[0] * b[0] - a[1] * b[1] - a[2] * b[2],
    ];
  }

  function clampBody(b) {
    if (!b || b.type === STATIC || !b.position || !b.velocity) return;
    b.position.z = 0;
    b.velocity.z = 0;
    if (b.previousPosition) b.previousPosition.z = 0;
    if (b.interpolatedPosition) b.interpolatedPosition.z = 0;
    if (b.force) b.force.z = 0;
    if (b.angularVelocity) { b.angularVelocity.x = 0; b.angularVelocity.y = 0; }
    if (b.torque) { b.torque.x = 0; b.torque.y = 0; }
    const q = b.quaternion;
    if (!q) return;
    const cur = [q.x, q.y, q.z, q.w];
    if (!initial.has(b)) initial.set(b, cur);
    const q0 = initial.get(b);
    // r = q * conj(q0) is the rotation since the start; keep only its part about z.
    const r = mul(cur, [-q0[0], -q0[1], -q0[2], q0[3]]);
    let z = r[2], w = r[3];
    const n = Math.hypot(z, w);
    if (n < 1e-12) { z = 0; w = 1; } else { z /= n; w /= n; }
    const out = mul([0, 0, z, w], q0);
    q.x = out[0]; q.y = out[1]; q.z = out[2]; q.w = out[3];
  }

  function clampWorld(world) {
    const bodies = world && world.bodies;
    if (!bodies) return;
    for (let i = 0; i < bodies.length; i++) clampBody(bodies[i]);
  }

  // Patch a World class (idempotent). Returns true when it was patched now.
  window.__visphyConstrain2D = function (World) {
    const proto = World && World.prototype;
    if (!proto || patched.has(proto)) return false;
    const name = typeof proto.internalStep === 'function' ? 'internalStep' : 'step';
    const original = proto[name];
    if (typeof original !== 'function') return false;
    proto[name] = function () {
      clampWorld(this);
      const result = original.apply(this, arguments);
      clampWorld(this);
      return result;
    };
    patched.add(proto);
    return true;
  };
  window.__visphyClamp2D = clampWorld;  // for tests and for programs that want it explicitly

  if (window.CANNON && window.CANNON.World) window.__visphyConstrain2D(window.CANNON.World);
})();
