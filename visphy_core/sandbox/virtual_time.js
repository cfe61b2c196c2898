// visphy virtual clock: injected before any page script so the program never sees real time.
// requestAnimationFrame, performance.now, Date, setTimeout/setInterval, requestIdleCallback and
// Math.random are replaced; the host advances time with __visphy.advanceTo(ms) and reads frames
// with __visphy.captureAt(t) (canvas readback) or __visphy.prepareScreenshot(t) followed by a page
// screenshot (pages without a canvas: SVG, DOM). Document animations (SMIL, CSS animations and
// transitions, Web Animations) are paused and seeked to the virtual time in screenshot mode.
// Same program + same config => same sequence of callbacks => same frames.
// It also logs the page's attempts to reach outside its origin (fetch/XHR of file:// and other
// hosts, beacons, WebRTC, pop-ups) for the scene log: the network namespace and the request
// interception of the host are what block them; WebRTC and window.open are refused here too.
(() => {
  const CONFIG = window.__VISPHY_CONFIG__ || {};
  const TICK_MS = CONFIG.tickMs || 1000 / 60;
  const EPOCH_MS = CONFIG.epochMs || 1700000000000;
  let now = 0;            // virtual milliseconds since page start
  let nextTick = 0;       // index of the next animation tick (tick i runs at i * TICK_MS)
  let nextId = 1;
  const timers = new Map(); // id -> {due, seq, fn, args, interval}
  const readyChecks = [];   // trusted-template predicates: the page may be captured once all hold
  // Screenshot mode: SMIL / CSS / Web Animations follow `now` instead of the real timeline.
  const syncDocumentAnimations = CONFIG.capture === 'screenshot';
  let timerSeq = 0;
  let rafQueue = new Map();  // id -> callback
  const errors = [];
  const logs = [];
  const attempts = [];
  const ORIGIN = CONFIG.origin || location.origin;
  const RealURL = URL;

  // Record an attempt to reach `url` (relative URLs resolve against the page); the page's own
  // origin and data:/blob: URLs are not attempts.
  function attempt(kind, url) {
    let u = '';
    try { u = String(url); } catch (e) { u = '?'; }
    try { u = new RealURL(u, location.href).href; } catch (e) { /* keep it as written */ }
    if (u.startsWith(ORIGIN + '/') || u.startsWith('data:') || u.startsWith('blob:') ||
        u === 'about:blank') return;
    record(`${kind} ${u.slice(0, 300)}`);
  }
  // Same-origin frames report to the top page, whose log the host reads.
  function record(entry) {
    if (window !== window.top) {
      try { window.top.__visphy.reportAttempt(entry); return; } catch (e) { /* not reachable */ }
    }
    if (attempts.length < 200) attempts.push(String(entry).slice(0, 310));
  }
  function lock(obj, name, value) {
    try { Object.defineProperty(obj, name, { value, writable: false, configurable: false }); }
    catch (e) { /* already locked */ }
  }

  const realFetch = window.fetch;
  window.fetch = function (input, init) {
    attempt('fetch', input && typeof input === 'object' && 'url' in input ? input.url : input);
    return realFetch.apply(this, arguments);
  };
  const realOpen = XMLHttpRequest.prototype.open;
  XMLHttpRequest.prototype.open = function (method, url) {
    attempt('xhr', url);
    return realOpen.apply(this, arguments);
  };
  if (navigator.sendBeacon) {
    const realBeacon = navigator.sendBeacon.bind(navigator);
    navigator.sendBeacon = (url, data) => { attempt('ping', url); return realBeacon(url, data); };
  }
  // WebRTC is off: the constructor logs what it was asked to reach and throws.
  function NoPeerConnection(config) {
    const urls = [];
    try {
      for (const s of (config && config.iceServers) || []) urls.push(...[].concat(s.urls || s.url || []));
    } catch (e) { /* a hostile config object */ }
    record(`webrtc ${urls.map(String).join(',').slice(0, 300) || 'RTCPeerConnection'}`);
    throw new DOMException('WebRTC is disabled in the visphy sandbox', 'NotSupportedError');
  }
  if (!CONFIG.realWebRTC) {  // (tests only: show that the browser's own policy holds too)
    for (const name of ['RTCPeerConnection', 'webkitRTCPeerConnection']) lock(window, name, NoPeerConnection);
  }
  // Pop-ups and dialogs: no new windows; dialogs answer at once.
  lock(window, 'open', function (url) { attempt('popup', url === undefined ? 'about:blank#popup' : url); return null; });
  window.alert = () => undefined;
  window.confirm = () => false;
  window.prompt = () => null;
  window.print = () => undefined;

  // Seeded PRNG (mulberry32) so Math.random is reproducible.
  let seed = (CONFIG.seed >>> 0) || 12345;
  Math.random = function () {
    seed = (seed + 0x6D2B79F5) >>> 0;
    let t = seed;
    t = Math.imul(t ^ (t >>> 15), t | 1);
    t ^= t + Math.imul(t ^ (t >>> 7), t | 61);
    return ((t ^ (t >>> 14)) >>> 0) / 4294967296;
  };

  const perf = window.performance;
  const realPerfNow = perf.now;  // the host's capture budget is real time; the page sees `now`
  Object.defineProperty(perf, 'now', { value: () => now, configurable: true });
  const RealDate = Date;
  function VDate(...args) {
    if (!(this instanceof VDate)) return new RealDate(EPOCH_MS + now).toString();
    return args.length ? new RealDate(...args) : new RealDate(EPOCH_MS + now);
  }
  VDate.prototype = RealDate.prototype;
  VDate.now = () => EPOCH_MS + Math.floor(now);
  VDate.UTC = RealDate.UTC;
  VDate.parse = RealDate.parse;
  window.Date = VDate;

  function addTimer(fn, ms, args, interval) {
    const id = nextId++;
    const delay = Math.max(0, Number(ms) || 0);
    timers.set(id, { due: now + delay, seq: timerSeq++, fn, args, interval: interval ? Math.max(delay, 1) : 0 });
    return id;
  }
  window.setTimeout = (fn, ms, ...args) => addTimer(fn, ms, args, false);
  window.setInterval = (fn, ms, ...args) => addTimer(fn, ms, args, true);
  window.clearTimeout = window.clearInterval = (id) => { timers.delete(id); };
  window.requestAnimationFrame = (cb) => { const id = nextId++; rafQueue.set(id, cb); return id; };
  window.cancelAnimationFrame = (id) => { rafQueue.delete(id); };
  window.requestIdleCallback = (cb) => addTimer(() => cb({ didTimeout: false, timeRemaining: () => 0 }), 0, [], false);
  window.cancelIdleCallback = window.clearTimeout;

  // MessageChannel: a message between the two ports of a channel is a real task, and whether it
  // runs before the host's next capture depends on the machine's load. Here it waits in a queue
  // that is delivered, in posting order, at the next animation tick (after the microtasks of the
  // current capture): one round of messages between two frames, whatever the load. Messages
  // carrying a transfer list, and ports not made by this page's MessageChannel, stay real.
  const peers = new WeakMap();
  const closedPorts = new WeakSet();
  let messages = [];
  const RealMessageChannel = window.MessageChannel;
  const realPortPost = typeof MessagePort === 'function' ? MessagePort.prototype.postMessage : null;
  if (typeof RealMessageChannel === 'function' && typeof MessagePort === 'function') {
    const realPost = MessagePort.prototype.postMessage;
    const realClose = MessagePort.prototype.close;
    const VMessageChannel = function MessageChannel() {
      if (!new.target) throw new TypeError("Failed to construct 'MessageChannel': Please use the 'new' operator");
      const ch = new RealMessageChannel();
      peers.set(ch.port1, ch.port2);
      peers.set(ch.port2, ch.port1);
      return ch;
    };
    VMessageChannel.prototype = RealMessageChannel.prototype;
    window.MessageChannel = VMessageChannel;
    MessagePort.prototype.postMessage = function (message, transfer) {
      const peer = peers.get(this);
      const list = Array.isArray(transfer) ? transfer : (transfer && transfer.transfer) || [];
      if (!peer || list.length) return realPost.apply(this, arguments);
      if (closedPorts.has(this)) return undefined;
      messages.push({ peer, data: structuredClone(message) });  // DataCloneError as the real one
      return undefined;
    };
    MessagePort.prototype.close = function () {
      closedPorts.add(this);
      const peer = peers.get(this);
      if (peer) closedPorts.add(peer);
      return realClose.apply(this, arguments);
    };
  }
  function deliverMessages() {
    const batch = messages; messages = [];
    for (const m of batch) {
      if (closedPorts.has(m.peer)) continue;
      // a throwing listener is reported by the page's error handler, as a real message task's is
      m.peer.dispatchEvent(new MessageEvent('message', { data: m.data }));
    }
  }

  function report(where, e) {
    const msg = (e && e.stack) ? String(e.stack) : String(e);
    if (errors.length < 200) errors.push(`${where} at t=${now.toFixed(1)}ms: ${msg}`.slice(0, 2000));
  }
  window.addEventListener('error', (ev) => report('uncaught error', ev.error || ev.message));
  window.addEventListener('unhandledrejection', (ev) => report('unhandled rejection', ev.reason));

  function runTimersUntil(t) {
    for (;;) {
      let best = null, bestId = null;
      for (const [id, tm] of timers) {
        if (tm.due <= t && (best === null || tm.due < best.due || (tm.due === best.due && tm.seq < best.seq))) {
          best = tm; bestId = id;
        }
      }
      if (best === null) return;
      now = Math.max(now, best.due);
      if (best.interval) { best.due += best.interval; best.seq = timerSeq++; } else { timers.delete(bestId); }
      if (syncDocumentAnimations) syncSmilClock();
      try { typeof best.fn === 'function' ? best.fn(...best.args) : (0, eval)(String(best.fn)); }
      catch (e) { report('timer', e); }
    }
  }

  function runAnimationFrame() {
    const queue = rafQueue; rafQueue = new Map();
    for (const cb of queue.values()) {
      try { cb(now); } catch (e) { report('requestAnimationFrame', e); }
    }
  }

  // Advance virtual time to `target` ms, running timers and one animation tick per TICK_MS
  // (the first tick at t = 0, so a program that draws only in requestAnimationFrame has a frame 0).
  function advanceTo(target) {
    while (nextTick * TICK_MS <= target + 1e-9) {
      const tickTime = nextTick * TICK_MS;
      nextTick += 1;
      if (messages.length) deliverMessages();
      runTimersUntil(tickTime);
      now = Math.max(now, tickTime);
      if (syncDocumentAnimations) syncSmilClock();
      runAnimationFrame();
      if (syncDocumentAnimations) stampAnimations();
    }
    runTimersUntil(target);
    now = Math.max(now, target);
  }

  // Document animations run on the real document timeline; in screenshot mode every one of them
  // is paused when first seen (birth = the virtual time it appeared) and seeked to `now - birth`
  // before each capture. SMIL timelines are paused and seeked per outermost <svg>.
  const births = new WeakMap();
  const realAnimate = Element.prototype.animate;
  Element.prototype.animate = function (...args) {
    const anim = realAnimate.apply(this, args);
    births.set(anim, now);
    if (syncDocumentAnimations) {
      try { anim.pause(); anim.currentTime = 0; } catch (e) { /* ignore */ }
    }
    return anim;
  };
  function stampAnimations() {
    if (!document.getAnimations) return;
    for (const anim of document.getAnimations()) {
      if (!births.has(anim)) {
        births.set(anim, now);
        try { anim.pause(); } catch (e) { /* ignore */ }
      }
    }
  }
  // SMIL clocks follow `now` at every tick, so beginElement() from a timer starts on time.
  function seekSmil() {
    for (const svg of document.querySelectorAll('svg')) {
      if (svg.ownerSVGElement || typeof svg.setCurrentTime !== 'function') continue;
      if (!svg.querySelector('animate, animateTransform, animateMotion, set')) continue;
      try { svg.pauseAnimations(); svg.setCurrentTime(now / 1000); } catch (e) { /* ignore */ }
    }
  }
  let smilAt = -1;
  function syncSmilClock() {
    if (smilAt !== now) { smilAt = now; seekSmil(); }
  }
  function seekDocumentAnimations() {
    stampAnimations();
    if (document.getAnimations) {
      for (const anim of document.getAnimations()) {
        try { anim.pause(); anim.currentTime = Math.max(0, now - births.get(anim)); }
        catch (e) { /* an animation that refuses seeking stays where it is */ }
      }
    }
    smilAt = now;
    seekSmil();
  }

  // Recording helper of the upstream contract: the program names its canvas and clip length.
  let recording = null;
  // Accepts a canvas, an <svg>, or what a drawing library hands out for one: a renderer or
  // buffer object holding its element as .elt, .domElement or .canvas (a 2D context: .canvas).
  function unwrapTarget(x) {
    for (let i = 0; i < 3 && x && !(x instanceof Element); i++) {
      x = x.elt || x.domElement || x.canvas || null;
    }
    return x instanceof Element ? x : null;
  }
  window.setupRecording = (canvas, durationMs) => {
    recording = { canvas: unwrapTarget(canvas), durationMs: Number(durationMs) || null };
    return { start() {}, stop() {} };
  };

  function pickCanvas() {
    if (recording && recording.canvas instanceof HTMLCanvasElement) return recording.canvas;
    // The largest canvas, preferring ones that are displayed (offscreen buffers are hidden).
    let best = null, score = -1;
    for (const c of document.querySelectorAll('canvas')) {
      const shown = c.getClientRects().length > 0 ? 1 : 0;
      const s = shown * 1e9 + c.width * c.height;
      if (s > score) { best = c; score = s; }
    }
    return best;
  }

  // Something a screenshot can show: an <svg> or a canvas (or the recorded element).
  function hasDrawable() {
    if (recording && recording.canvas && recording.canvas.isConnected) return true;
    return !!document.querySelector('svg, canvas');
  }

  // WebGL canvases keep their drawing buffer so a capture always sees the last rendered frame.
  // The context each canvas hands out is remembered for the raw readback below.
  const realGetContext = HTMLCanvasElement.prototype.getContext;
  const realToDataURL = HTMLCanvasElement.prototype.toDataURL;
  const contexts = new WeakMap();  // canvas -> its first context
  HTMLCanvasElement.prototype.getContext = function (type, attrs) {
    if (typeof type === 'string' && type.startsWith('webgl')) {
      attrs = Object.assign({}, attrs || {}, { preserveDrawingBuffer: true });
    }
    const ctx = realGetContext.call(this, type, attrs);
    try { if (ctx && !contexts.has(this)) contexts.set(this, ctx); } catch (e) { /* ignore */ }
    return ctx;
  };

  // Raw readback: the captured canvas' pixels without a PNG round trip (toDataURL encodes a PNG
  // on the page's thread, the host decodes it again). WebGL: readPixels of the drawing buffer,
  // with the program's framebuffer and pixel-pack state put back as they were; 2D: a copy into a
  // private OffscreenCanvas read with getImageData (the program's own context is never read,
  // so nothing about it changes). The pixels go to the host run-length encoded (runs of one
  // RGBA value; a flat-coloured 512x512 frame is a few kB) or, when that is no smaller, as they
  // are. Only frames that are fully opaque, 8-bit sRGB and the canvas' own size take this path:
  // there the pixels are exactly what toDataURL encodes. Anything else (translucent pixels,
  // another colour space or format, a lost context, a bitmap or WebGPU context) is read with
  // toDataURL as before. Every built-in used here is taken before the program runs.
  const apply = Reflect.apply;
  const defineProperty = Object.defineProperty;
  const construct = Reflect.construct;
  const getPrototypeOf = Object.getPrototypeOf;
  const fromCharCode = String.fromCharCode;
  const realBtoa = window.btoa;
  const U8 = Uint8Array, U32 = Uint32Array;
  const subarray = U8.prototype.subarray;
  const littleEndian = new U8(new U32([1]).buffer)[0] === 1;
  function getter(proto, name) {
    const d = proto && Object.getOwnPropertyDescriptor(proto, name);
    return d ? d.get : undefined;
  }
  function setter(proto, name) {
    const d = proto && Object.getOwnPropertyDescriptor(proto, name);
    return d ? d.set : undefined;
  }
  const glKinds = [];
  for (const [name, webgl2] of [['WebGLRenderingContext', false], ['WebGL2RenderingContext', true]]) {
    const C = window[name];
    if (typeof C !== 'function') continue;
    const p = C.prototype;
    glKinds.push({
      proto: p, webgl2, readPixels: p.readPixels, getParameter: p.getParameter,
      bindFramebuffer: p.bindFramebuffer, pixelStorei: p.pixelStorei, bindBuffer: p.bindBuffer,
      isContextLost: p.isContextLost, getContextAttributes: p.getContextAttributes,
      width: getter(p, 'drawingBufferWidth'), height: getter(p, 'drawingBufferHeight'),
      colorSpace: getter(p, 'drawingBufferColorSpace'), format: getter(p, 'drawingBufferFormat'),
    });
  }
  const C2D = window.CanvasRenderingContext2D && CanvasRenderingContext2D.prototype;
  const c2dAttributes = C2D && C2D.getContextAttributes;
  const Offscreen = window.OffscreenCanvas;
  const O2D = window.OffscreenCanvasRenderingContext2D && OffscreenCanvasRenderingContext2D.prototype;
  const offscreenGetContext = Offscreen && Offscreen.prototype.getContext;
  const o2d = O2D && { drawImage: O2D.drawImage, getImageData: O2D.getImageData,
    setComposite: setter(O2D, 'globalCompositeOperation'), data: getter(ImageData.prototype, 'data') };
  const GL = { FRAMEBUFFER: 0x8D40, FRAMEBUFFER_BINDING: 0x8CA6, READ_FRAMEBUFFER: 0x8CA8,
    READ_FRAMEBUFFER_BINDING: 0x8CAA, READ_BUFFER: 0x0C02, BACK: 0x0405, PACK_ALIGNMENT: 0x0D05,
    PACK_ROW_LENGTH: 0x0D02, PACK_SKIP_ROWS: 0x0D03, PACK_SKIP_PIXELS: 0x0D04,
    PIXEL_PACK_BUFFER: 0x88EB, PIXEL_PACK_BUFFER_BINDING: 0x88ED, RGBA: 0x1908,
    UNSIGNED_BYTE: 0x1401, RGBA8: 0x8058, RGB8: 0x8051 };
  let pixelBuffer = null;
  function pixels(n) {
    if (!pixelBuffer || pixelBuffer.length !== n) pixelBuffer = new U8(n);
    return pixelBuffer;
  }

  // The drawing buffer of a WebGL context, bottom row first, or null when it cannot be read
  // exactly as toDataURL would.
  function readWebGL(c, ctx, kind) {
    if (apply(kind.isContextLost, ctx, [])) return null;
    const attrs = apply(kind.getContextAttributes, ctx, []);
    if (!attrs || attrs.preserveDrawingBuffer !== true) return null;
    const w = apply(kind.width, ctx, []), h = apply(kind.height, ctx, []);
    if (w !== c.width || h !== c.height || w * h === 0) return null;
    if (kind.colorSpace && apply(kind.colorSpace, ctx, []) !== 'srgb') return null;
    if (kind.format) {
      const f = apply(kind.format, ctx, []);
      if (f !== GL.RGBA8 && f !== GL.RGB8) return null;
    }
    const get = (pname) => apply(kind.getParameter, ctx, [pname]);
    const set = (pname, v) => apply(kind.pixelStorei, ctx, [pname, v]);
    const target = kind.webgl2 ? GL.READ_FRAMEBUFFER : GL.FRAMEBUFFER;
    const bound = get(kind.webgl2 ? GL.READ_FRAMEBUFFER_BINDING : GL.FRAMEBUFFER_BINDING);
    const pack = {};
    const packNames = kind.webgl2 ? ['PACK_ALIGNMENT', 'PACK_ROW_LENGTH', 'PACK_SKIP_ROWS',
      'PACK_SKIP_PIXELS'] : ['PACK_ALIGNMENT'];
    for (const name of packNames) pack[name] = get(GL[name]);
    const packBuffer = kind.webgl2 ? get(GL.PIXEL_PACK_BUFFER_BINDING) : null;
    const want = (name) => (name === 'PACK_ALIGNMENT' ? 4 : 0);
    if (bound) apply(kind.bindFramebuffer, ctx, [target, null]);
    let out = null, changed = false;
    try {
      if (!kind.webgl2 || get(GL.READ_BUFFER) === GL.BACK) {
        changed = true;
        if (packBuffer) apply(kind.bindBuffer, ctx, [GL.PIXEL_PACK_BUFFER, null]);
        for (const name of packNames) if (pack[name] !== want(name)) set(GL[name], want(name));
        out = pixels(w * h * 4);
        apply(kind.readPixels, ctx, [0, 0, w, h, GL.RGBA, GL.UNSIGNED_BYTE, out]);
      }
    } finally {
      if (changed) {
        for (const name of packNames) if (pack[name] !== want(name)) set(GL[name], pack[name]);
        if (packBuffer) apply(kind.bindBuffer, ctx, [GL.PIXEL_PACK_BUFFER, packBuffer]);
      }
      if (bound) apply(kind.bindFramebuffer, ctx, [target, bound]);
    }
    return out && { data: out, width: w, height: h, flipY: true };
  }

  let scratch = null;  // the private OffscreenCanvas 2D copies go through
  function read2D(c, ctx) {
    if (!o2d || !c2dAttributes) return null;
    const attrs = apply(c2dAttributes, ctx, []);
    if (!attrs || (attrs.colorSpace !== undefined && attrs.colorSpace !== 'srgb')) return null;
    if (attrs.colorType !== undefined && attrs.colorType !== 'unorm8') return null;
    if (attrs.pixelFormat !== undefined && attrs.pixelFormat !== 'uint8') return null;
    const w = c.width, h = c.height;
    if (w * h === 0) return null;
    if (!scratch || scratch.canvas.width !== w || scratch.canvas.height !== h) {
      const canvas = construct(Offscreen, [w, h]);
      scratch = { canvas, ctx: apply(offscreenGetContext, canvas, ['2d', { willReadFrequently: true }]) };
    }
    apply(o2d.setComposite, scratch.ctx, ['copy']);
    apply(o2d.drawImage, scratch.ctx, [c, 0, 0]);
    const image = apply(o2d.getImageData, scratch.ctx, [0, 0, w, h]);
    const data = apply(o2d.data, image, []);
    return { data: new U8(data.buffer, data.byteOffset, data.byteLength), width: w,
             height: h, flipY: false };
  }

  // Runs of equal pixels as (count, RGBA) pairs, or the pixels as they are when that is no
  // smaller; null when a pixel is not fully opaque.
  function encodeRuns(bytes) {
    const px = new U32(bytes.buffer, bytes.byteOffset, bytes.byteLength >> 2);
    const n = px.length;
    const runs = new U32(2 * n);
    let k = 0;
    for (let i = 0; i < n;) {
      const v = px[i];
      if ((v >>> 24) !== 255) return null;
      let j = i + 1;
      while (j < n && px[j] === v) j++;
      runs[k++] = j - i;
      runs[k++] = v;
      i = j;
    }
    if (k >= n) return { kind: 'raw', bytes };
    return { kind: 'runs', bytes: new U8(runs.buffer, 0, k * 4) };
  }

  function base64(u8) {
    let s = '';
    for (let i = 0; i < u8.length; i += 0x8000) {
      s += apply(fromCharCode, null, apply(subarray, u8, [i, i + 0x8000]));
    }
    return apply(realBtoa, window, [s]);
  }

  function readRaw(c) {
    if (!littleEndian) return null;
    const ctx = contexts.get(c);
    if (!ctx) return null;
    const proto = getPrototypeOf(ctx);
    let read = null;
    for (const kind of glKinds) if (kind.proto === proto) read = readWebGL(c, ctx, kind);
    if (C2D && proto === C2D) read = read2D(c, ctx);
    if (!read) return null;
    const enc = encodeRuns(read.data);
    if (!enc) return null;
    const data = base64(enc.bytes);
    return { kind: enc.kind, data, size: data.length, width: read.width, height: read.height,
             flipY: read.flipY };
  }

  for (const level of ['log', 'info', 'warn', 'error']) {
    console[level] = (...args) => {
      // Kept here only (bounded): nothing goes to Chromium's console, so a page that logs
      // without end costs no host time.
      if (logs.length < 500) {
        let line = '';
        try { line = args.map((a) => String(a).slice(0, 500)).join(' ').slice(0, 500); }
        catch (e) { line = '(unprintable)'; }
        logs.push(`[${level}] ` + line);
      }
    };
  }

  // A real task boundary between two frames of one span: the page's pending microtasks (promise
  // chains resumed by the last animation tick) run before the next frame is stepped, as they do
  // between two host calls. A private channel of the real MessageChannel, wired before any
  // program runs; the page's own channels are virtual (delivered in advanceTo).
  const spanChannel = typeof RealMessageChannel === 'function' && realPortPost
    ? new RealMessageChannel() : null;
  let spanWake = null;
  if (spanChannel) spanChannel.port1.onmessage = () => { const wake = spanWake; spanWake = null; if (wake) wake(); };
  const RealPromise = Promise;
  function taskBoundary() {
    return new RealPromise((resolve) => {
      if (!spanChannel) { resolve(); return; }
      spanWake = resolve;
      apply(realPortPost, spanChannel.port2, [0]);
    });
  }

  // One frame at `t` ms: raw where exact (`raw` true), else a PNG data URL; `png: null` without
  // a canvas. `lastPayloadChars`: the size of the frame's payload (0 without a canvas).
  let lastPayloadChars = 0;
  function capture(t, raw) {
    advanceTo(t);
    lastPayloadChars = 0;
    const c = pickCanvas();
    if (!c) return { png: null, width: 0, height: 0 };
    let out = null;
    if (raw) {
      try { out = readRaw(c); } catch (e) { out = null; }
    }
    if (out) {
      lastPayloadChars = out.size;
      return { [out.kind]: out.data, width: out.width, height: out.height, flipY: out.flipY };
    }
    const png = apply(realToDataURL, c, ['image/png']);
    lastPayloadChars = png.length;
    return { png, width: c.width, height: c.height };
  }

  const api = {
    advanceTo,
    attempts: () => attempts.slice(),
    reportAttempt: (entry) => record(entry),
    now: () => now,
    errors: () => errors.slice(),
    logs: () => logs.slice(),
    recording: () => recording && { durationMs: recording.durationMs },
    // Trusted templates register predicates (e.g. "the library finished loading and set up"); the
    // host waits, in real time and within the page's time limit, until all hold.
    addReadyCheck(fn) { readyChecks.push(fn); },
    isReady() {
      if (errors.length) return true;  // a page that already failed is captured as it is
      for (const fn of readyChecks) {
        try { if (!fn()) return false; } catch (e) { return false; }
      }
      return true;
    },
    // Advance to `t` ms, seek document animations there, and say whether there is anything to
    // screenshot; the host then captures the viewport.
    prepareScreenshot(t) {
      advanceTo(t);
      if (syncDocumentAnimations) seekDocumentAnimations();
      return { drawable: hasDrawable() };
    },
    // Advance to `t` ms and return the chosen canvas as a PNG data URL (or null without canvas).
    captureAt(t) { return capture(t, false); },
    // The same frame, read raw (`runs` or `raw`, base64) where that is exact, else as `png`.
    captureRawAt(t) { return capture(t, true); },
    // Several frames in one call (one host round trip instead of one per frame): the answers of
    // captureRawAt (`raw` true) or captureAt for `times` in order, stopping after the first frame
    // without a canvas, or once `budgetMs` of real time or `maxChars` of payload have been spent
    // (at least one frame is always taken); the host asks again from where it stopped. `first`:
    // answer `{notReady: true}` instead while a ready check does not hold (the host then waits
    // for it). The page's state (errors, logs, attempts) is read by a call of its own: in the
    // time that call takes, a navigation the last frames started reaches the host's handlers.
    async captureSpan(times, raw, budgetMs, maxChars, first) {
      if (first && !api.isReady()) return { notReady: true };
      const start = apply(realPerfNow, perf, []);
      const out = [];
      let chars = 0;
      for (let i = 0; i < times.length; i++) {
        if (i > 0) await taskBoundary();
        const shot = capture(times[i], raw);
        defineProperty(out, i, { value: shot, writable: true, enumerable: true, configurable: true });
        chars += lastPayloadChars;
        if (lastPayloadChars === 0 || chars >= maxChars
            || apply(realPerfNow, perf, []) - start >= budgetMs) break;
      }
      return { frames: out };
    },
  };
  // The host's handle cannot be replaced or deleted by the page.
  lock(window, '__visphy', Object.freeze(api));
})();
