// visphy report: one control drives every clip of a scene (ground truth, generated, spec
// track), and the scene list can be filtered by outcome and difficulty. No network, no data
// in this script: everything it reads comes from the page's elements.
(function () {
  'use strict';

  function syncGroup(group) {
    var videos = Array.prototype.slice.call(group.querySelectorAll('video'));
    var play = group.querySelector('[data-act=play]');
    var scrub = group.querySelector('input[type=range]');
    var label = group.querySelector('.frame-label');
    var speed = group.querySelector('select[data-act=rate]');
    if (!videos.length || !play) { return; }
    var fps = parseFloat(group.getAttribute('data-fps')) || 0;
    var frames = parseInt(group.getAttribute('data-frames'), 10) || 0;
    var playing = false;

    function live() { return videos.filter(function (v) { return !v.error; }); }
    function master() { return live()[0] || videos[0]; }
    function frameAt(t) {
      if (!fps) { return 0; }
      return Math.max(0, Math.min(frames - 1, Math.floor(t * fps + 1e-6)));
    }
    function show(t) {
      var k = frameAt(t);
      if (scrub && document.activeElement !== scrub) { scrub.value = String(k); }
      if (label) {
        label.textContent = fps ? 'frame ' + (k + 1) + '/' + frames + ' · ' + t.toFixed(2) + ' s'
                                : t.toFixed(2) + ' s';
      }
    }
    function seek(t) {
      live().forEach(function (v) {
        var end = isFinite(v.duration) ? v.duration : t;
        v.currentTime = Math.min(t, Math.max(0, end - 1e-3));
      });
      show(t);
    }
    function seekFrame(k) {
      k = Math.max(0, Math.min((frames || 1) - 1, k));
      seek(fps ? (k + 0.5) / fps : 0);
    }
    function tick() {
      if (!playing) { return; }
      var m = master();
      var t = m.currentTime;
      var slack = fps ? 0.5 / fps : 0.05;
      live().forEach(function (v) {
        if (v !== m && Math.abs(v.currentTime - t) > slack) { v.currentTime = t; }
        if (v.paused) { v.play().catch(function () {}); }
      });
      show(t);
      window.requestAnimationFrame(tick);
    }
    function start() {
      playing = true;
      play.textContent = '❚❚ pause';
      var t = master().currentTime;
      live().forEach(function (v) {
        v.currentTime = t;
        v.play().catch(function () {});
      });
      window.requestAnimationFrame(tick);
    }
    function stop() {
      playing = false;
      play.textContent = '▶ play';
      live().forEach(function (v) { v.pause(); });
      seek(master().currentTime);
    }
    play.addEventListener('click', function () { if (playing) { stop(); } else { start(); } });
    group.querySelectorAll('[data-act=step]').forEach(function (b) {
      b.addEventListener('click', function () {
        if (playing) { stop(); }
        seekFrame(frameAt(master().currentTime) + parseInt(b.getAttribute('data-by'), 10));
      });
    });
    if (scrub) {
      scrub.addEventListener('input', function () {
        if (playing) { stop(); }
        seekFrame(parseInt(scrub.value, 10));
      });
    }
    if (speed) {
      speed.addEventListener('change', function () {
        var r = parseFloat(speed.value) || 1;
        videos.forEach(function (v) { v.playbackRate = r; });
      });
    }
    videos.forEach(function (v) {
      v.addEventListener('error', function () {
        var note = document.createElement('p');
        note.className = 'note bad';
        note.textContent = 'this browser cannot play this clip';
        v.parentNode.appendChild(note);
      });
    });
    show(0);
    group.setAttribute('data-ready', '1');
  }

  function filters() {
    var outcome = document.getElementById('filter-outcome');
    var difficulty = document.getElementById('filter-difficulty');
    var count = document.getElementById('filter-count');
    if (!outcome || !difficulty) { return; }
    var items = document.querySelectorAll('[data-outcome]');
    function apply() {
      var shown = 0;
      items.forEach(function (el) {
        var ok = (!outcome.value || el.getAttribute('data-outcome') === outcome.value) &&
                 (!difficulty.value || el.getAttribute('data-difficulty') === difficulty.value);
        el.hidden = !ok;
        if (ok && el.tagName === 'SECTION') { shown += 1; }
      });
      if (count) {
        count.textContent = shown + ' of ' + document.querySelectorAll('section.scene').length +
                            ' scenes';
      }
    }
    outcome.addEventListener('change', apply);
    difficulty.addEventListener('change', apply);
    apply();
  }

  document.querySelectorAll('.sync').forEach(syncGroup);
  filters();
}());
