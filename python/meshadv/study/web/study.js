// The meshadv perceptual study: the MeshAdv two-alternative forced choice (2AFC) protocol, run from a static folder.
//
// plan.js sets window.STUDY_PLAN (written by `meshadv study export`): settings, stimuli and each participant's trials.
// The participant is ?participant=N in the URL (an index into the plan), else one picked at random. Every trial:
// a fixation cross, the image for exactly `exposure_ms` in the middle of the screen (onset and offset taken from
// requestAnimationFrame frame times, so the measured exposure is what was on screen), then the two answers (true
// class and target, in the plan's order) with unlimited time, by key (F/1 left, J/2 right) or mouse. The answers are
// downloadable as CSV and JSON at the end and, when the plan names a post_url, sent there.
(function () {
  "use strict";

  var PLAN = window.STUDY_PLAN;
  var S = PLAN.settings;
  var $ = function (id) { return document.getElementById(id); };
  var state = { phase: "loading", index: 0, answers: [], trials: [], participant: null, source: "", query: {},
                session: randomHex(8), choicesShownAt: 0, current: null, frameMs: null };
  window.STUDY_STATE = state;  // for debugging and the browser test

  // A random id of this run of the page: two people given the same participant number stay apart in the analysis.
  function randomHex(bytes) {
    var a = new Uint8Array(bytes);
    window.crypto.getRandomValues(a);
    return Array.prototype.map.call(a, function (b) { return (b + 256).toString(16).slice(1); }).join("");
  }

  function fail(message) {
    $("error").textContent = message;
    $("error").hidden = false;
    $("start").disabled = true;
    $("start").textContent = "Cannot start";
  }

  function parseQuery() {
    var out = {};
    new URLSearchParams(window.location.search).forEach(function (value, key) { out[key] = value; });
    return out;
  }

  function pickParticipant() {
    var n = PLAN.participants.length;
    if (state.query.participant !== undefined) {
      var p = Number(state.query.participant);
      if (!Number.isInteger(p) || p < 0 || p >= n) {
        fail("participant must be a whole number from 0 to " + (n - 1) + ", got \"" + state.query.participant + "\"");
        return null;
      }
      state.source = "url";
      return p;
    }
    var r = new Uint32Array(1);
    window.crypto.getRandomValues(r);
    state.source = "random";
    return r[0] % n;
  }

  function preload(trials) {
    var loads = trials.map(function (t) {
      var img = new Image();
      img.src = "images/" + PLAN.stimuli[t.image_id].file;
      return img.decode().then(function () { return img; });
    });
    return Promise.all(loads);
  }

  function showScreen(id) {
    ["intro", "stage", "done"].forEach(function (s) { $(s).hidden = s !== id; });
  }

  function updateProgress() {
    var n = state.trials.length;
    var k = Math.min(state.index + 1, n);
    $("progress-text").textContent = "Trial " + k + " of " + n;
    $("progress-fill").style.width = (100 * state.index / n) + "%";
  }

  function nextFrame() {
    return new Promise(function (resolve) { window.requestAnimationFrame(resolve); });
  }

  function wait(ms) {
    return new Promise(function (resolve) { window.setTimeout(resolve, ms); });
  }

  // Median frame interval over a few frames: the display's refresh period, used to stop the exposure on the frame
  // nearest to its target length.
  function measureFrame() {
    var times = [];
    function loop(t) {
      times.push(t);
      return times.length < 12 ? nextFrame().then(loop) : null;
    }
    return nextFrame().then(loop).then(function () {
      var d = [];
      for (var i = 1; i < times.length; i++) { d.push(times[i] - times[i - 1]); }
      d.sort(function (a, b) { return a - b; });
      return d[Math.floor(d.length / 2)];
    });
  }

  // Show the image from one frame to the frame nearest `exposure_ms` later; resolve with the frame times.
  function expose(img) {
    var half = (state.frameMs || 16.7) / 2;
    return nextFrame().then(function (onset) {
      img.hidden = false;  // painted in the frame that starts at `onset`
      function tick(now) {
        if (now - onset >= S.exposure_ms - half) {
          img.hidden = true;  // removed in the frame that starts at `now`
          return { onset: onset, offset: now };
        }
        return nextFrame().then(tick);
      }
      return nextFrame().then(tick);
    });
  }

  function runTrial() {
    if (state.index >= state.trials.length) { return finish(); }
    updateProgress();
    var trial = state.trials[state.index];
    var stim = PLAN.stimuli[trial.image_id];
    var img = $("stimulus");
    img.src = "images/" + stim.file;
    img.width = S.image_px;
    img.height = S.image_px;
    state.phase = "fixation";
    $("choices").hidden = true;
    $("fixation").hidden = false;
    var fixStart = performance.now();
    var fixEnd = 0;
    return img.decode().then(function () {
      return wait(Math.max(0, S.fixation_ms - (performance.now() - fixStart)));
    }).then(function () {
      $("fixation").hidden = true;
      fixEnd = performance.now();
      state.phase = "exposure";
      return expose(img);
    }).then(function (times) {
      var left = trial.true_first ? stim.true_class : stim.target;
      var right = trial.true_first ? stim.target : stim.true_class;
      $("choice-left").textContent = left;
      $("choice-right").textContent = right;
      $("choices").hidden = false;
      state.current = { trial: trial, stim: stim, times: times, left: left, right: right,
                        fixation_ms: fixEnd - fixStart };
      state.choicesShownAt = performance.now();
      state.phase = "choice";
    });
  }

  function answer(side, input) {
    if (state.phase !== "choice") { return; }
    state.phase = "answered";
    var c = state.current;
    var now = performance.now();
    var chosen = side === "left" ? c.left : c.right;
    state.answers.push({
      study_id: S.study_id, session: state.session, participant: state.participant,
      participant_source: state.source, trial: state.index, image_id: c.trial.image_id, kind: c.stim.kind,
      true_class: c.stim.true_class, target: c.stim.target, victim: c.stim.victim, perturbation: c.stim.perturbation,
      distance: c.stim.distance, job_id: c.stim.job_id, left: c.left, right: c.right, true_first: c.trial.true_first,
      choice: chosen, chosen_side: side, correct: chosen === c.stim.true_class, input: input,
      fixation_ms: round(c.fixation_ms), exposure_ms: round(c.times.offset - c.times.onset),
      exposure_target_ms: S.exposure_ms, frame_ms: round(state.frameMs), onset_ms: round(c.times.onset),
      rt_ms: round(now - state.choicesShownAt), answered_at: new Date().toISOString(),
      user_agent: navigator.userAgent, query: JSON.stringify(state.query)
    });
    $("choices").hidden = true;
    state.index += 1;
    runTrial();
  }

  function round(x) { return x === null || x === undefined ? null : Math.round(x * 1000) / 1000; }

  var COLUMNS = ["study_id", "session", "participant", "participant_source", "trial", "image_id", "kind",
                 "true_class", "target", "victim", "perturbation", "distance", "job_id", "left", "right", "true_first", "choice",
                 "chosen_side", "correct", "input", "fixation_ms", "exposure_ms", "exposure_target_ms", "frame_ms",
                 "onset_ms", "rt_ms", "answered_at", "user_agent", "query"];

  function csvCell(v) {
    var s = v === null || v === undefined ? "" : String(v);
    return /[",\n\r]/.test(s) ? "\"" + s.replace(/"/g, "\"\"") + "\"" : s;
  }

  function toCsv(rows) {
    var lines = [COLUMNS.join(",")];
    rows.forEach(function (r) { lines.push(COLUMNS.map(function (k) { return csvCell(r[k]); }).join(",")); });
    return lines.join("\r\n") + "\r\n";
  }

  function payload() {
    return { study_id: S.study_id, session: state.session, participant: state.participant,
             participant_source: state.source, query: state.query, finished_at: new Date().toISOString(), answers: state.answers };
  }

  function download(text, type, name) {
    var a = document.createElement("a");
    a.href = URL.createObjectURL(new Blob([text], { type: type }));
    a.download = name;
    document.body.appendChild(a);
    a.click();
    document.body.removeChild(a);
  }

  function fileStem() { return "answers_" + S.study_id + "_p" + state.participant; }

  function post() {
    if (!S.post_url) { return; }
    var status = $("post-status");
    var body = JSON.stringify(payload());
    if (S.post_mode === "form") {  // e.g. Mechanical Turk's externalSubmit: a plain form POST that leaves the page
      var form = document.createElement("form");
      form.method = "POST";
      form.action = S.post_url;
      var fields = { answers: body, assignmentId: state.query.assignmentId || "" };
      Object.keys(fields).forEach(function (k) {
        var input = document.createElement("input");
        input.type = "hidden";
        input.name = k;
        input.value = fields[k];
        form.appendChild(input);
      });
      document.body.appendChild(form);
      status.textContent = "Sending your answers…";
      form.submit();
      return;
    }
    status.textContent = "Sending your answers…";
    // text/plain keeps this a "simple" cross-origin request (no preflight), which also works from file://.
    fetch(S.post_url, { method: "POST", headers: { "Content-Type": "text/plain;charset=UTF-8" }, body: body })
      .then(function (r) {
        status.textContent = r.ok ? "Your answers were sent." : "Sending failed (HTTP " + r.status +
          "): please download them and send the file.";
      })
      .catch(function () { status.textContent = "Sending failed: please download your answers and send the file."; });
  }

  function finish() {
    state.phase = "done";
    $("progress-fill").style.width = "100%";
    $("progress").hidden = true;
    showScreen("done");
    $("done-summary").textContent = "You answered " + state.answers.length + " questions.";
    post();
  }

  function start() {
    if (state.phase !== "ready") { return; }
    state.phase = "starting";
    showScreen("stage");
    $("progress").hidden = false;
    measureFrame().then(function (ms) { state.frameMs = ms; return runTrial(); });
  }

  document.addEventListener("keydown", function (e) {
    if (e.repeat) { return; }
    var key = e.key.toLowerCase();
    if (state.phase === "ready" && (key === " " || key === "enter")) { e.preventDefault(); start(); return; }
    if (state.phase !== "choice") { return; }
    if (key === "f" || key === "1") { answer("left", "key:" + key); }
    if (key === "j" || key === "2") { answer("right", "key:" + key); }
  });
  $("choice-left").addEventListener("click", function () { answer("left", "mouse"); });
  $("choice-right").addEventListener("click", function () { answer("right", "mouse"); });
  $("start").addEventListener("click", start);
  $("download-csv").addEventListener("click", function () {
    download(toCsv(state.answers), "text/csv", fileStem() + ".csv");
  });
  $("download-json").addEventListener("click", function () {
    download(JSON.stringify(payload(), null, 2), "application/json", fileStem() + ".json");
  });

  state.query = parseQuery();
  $("exposure-seconds").textContent = String(S.exposure_ms / 1000);
  var p = pickParticipant();
  if (p === null) { return; }
  state.participant = p;
  state.trials = PLAN.participants[p].trials;
  $("participant-line").textContent = "Participant " + p + (state.source === "random" ? " (picked at random)" : "") +
    ": " + state.trials.length + " questions.";
  preload(state.trials).then(function () {
    state.phase = "ready";
    $("start").disabled = false;
    $("start").textContent = "Start";
  }, function () { fail("Some images could not be loaded; the study folder is incomplete."); });
})();
