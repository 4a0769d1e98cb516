// The shot page: every take's player in sync (play, pause, frame steps, scrubbing), the keys
// on the timeline, and the decisions (approve with a note, publish) through the JSON API.
"use strict";
(function () {
  const data = JSON.parse(document.getElementById("shot-data").textContent);
  const csrf = document.querySelector('meta[name="csrf-token"]').content;
  const videos = Array.from(document.querySelectorAll("video[data-take]"));
  const fps = data.fps || 24;
  const first = data.frame_range ? data.frame_range[0] : 0;
  const count = data.frame_range ? Math.round(data.frame_range[1] - data.frame_range[0]) + 1 : 1;
  const scrub = document.getElementById("scrub");
  const frameLabel = document.getElementById("frame");
  const sourceLabel = document.getElementById("source");
  const message = document.getElementById("message");
  // Times this page set on a player itself: its own seek events are not a user's seek.
  const expected = new Map();
  let selected = null;

  const frameOf = (t) => Math.max(0, Math.min(count - 1, Math.floor(t * fps + 1e-3)));
  // A quarter frame in: safely inside the frame whatever the decoder rounds.
  const timeOf = (i) => (Math.max(0, Math.min(count - 1, i)) + 0.25) / fps;
  const lead = () => videos[0];

  function setTime(v, t) {
    if (Math.abs(v.currentTime - t) < 1e-4) return;
    expected.set(v, t);
    v.currentTime = t;
  }
  function seekAll(t, except) {
    videos.forEach((v) => { if (v !== except) setTime(v, t); });
    show(t);
  }
  function show(t) {
    const i = frameOf(t);
    const f = first + i;
    scrub.value = i;
    frameLabel.textContent = `frame ${f}` + (data.keys.includes(f) ? " KEY" : "");
    const labels = data.characters.map((c) => {
      const s = c.sources.find(([a, b]) => a < f && f < b);
      return s ? (data.characters.length > 1 ? `${c.path.split("/").slice(-3, -1).join("/")}: ` : "") + s[2] : null;
    }).filter(Boolean);
    sourceLabel.textContent = labels.join(" · ");
  }
  function playing() { return videos.some((v) => !v.paused); }
  function play() { videos.forEach((v) => { if (v.paused) v.play().catch(() => {}); }); }
  function pause() {
    videos.forEach((v) => { if (!v.paused) v.pause(); });
    if (videos.length) seekAll(timeOf(frameOf(lead().currentTime)));
  }
  function step(n) {
    pause();
    const t = videos.length ? lead().currentTime : timeOf(Number(scrub.value));
    seekAll(timeOf(frameOf(t) + n));
  }

  videos.forEach((v) => {
    v.addEventListener("seeking", () => {
      const want = expected.get(v);
      if (want !== undefined && Math.abs(v.currentTime - want) < 1e-3) { expected.delete(v); return; }
      expected.delete(v);
      seekAll(v.currentTime, v); // a user's seek on this player: the others follow
    });
    v.addEventListener("play", () => { if (videos.some((o) => o.paused)) play(); });
    v.addEventListener("pause", () => { if (!v.ended && playing()) pause(); });
  });
  // While playing, the first player is the clock: the others are pulled back within a frame.
  function tick() {
    if (videos.length && playing()) {
      const t = lead().currentTime;
      videos.slice(1).forEach((v) => { if (Math.abs(v.currentTime - t) > 1.0 / fps) setTime(v, t); });
      show(t);
    }
    requestAnimationFrame(tick);
  }
  requestAnimationFrame(tick);

  scrub.max = String(count - 1);
  scrub.addEventListener("input", () => { pause(); seekAll(timeOf(Number(scrub.value))); });
  const marks = document.getElementById("marks");
  data.keys.forEach((k) => {
    const m = document.createElement("button");
    m.type = "button";
    m.className = "key";
    m.title = `key ${k}`;
    m.dataset.frame = k;
    m.style.left = `${count > 1 ? (100 * (k - first)) / (count - 1) : 0}%`;
    m.addEventListener("click", () => { pause(); seekAll(timeOf(k - first)); });
    marks.appendChild(m);
  });
  document.getElementById("play").addEventListener("click", () => (playing() ? pause() : play()));
  document.getElementById("prev").addEventListener("click", () => step(-1));
  document.getElementById("next").addEventListener("click", () => step(1));
  show(0);

  function say(text, ok) {
    message.hidden = false;
    message.textContent = text;
    message.className = ok ? "ok" : "error";
  }
  async function post(action, body) {
    const r = await fetch(`/api/shots/${data.key.split("/").map(encodeURIComponent).join("/")}/${action}`, {
      method: "POST",
      headers: { "Content-Type": "application/json", "X-CSRF-Token": csrf },
      body: JSON.stringify(body),
      credentials: "same-origin",
    });
    const out = await r.json().catch(() => ({ detail: `${r.status} ${r.statusText}` }));
    if (!r.ok) throw new Error(typeof out.detail === "string" ? out.detail : JSON.stringify(out.detail));
    return out;
  }

  const dialog = document.getElementById("confirm-dialog");
  const confirmButton = document.querySelector('[data-action="confirm"]');
  function ask(take) {
    selected = take;
    document.getElementById("confirm-take").textContent = take;
    if (dialog.showModal) dialog.showModal(); else dialog.setAttribute("open", "");
    const reviewer = document.getElementById("reviewer");
    if (!reviewer.value) reviewer.value = localStorage.getItem("tween-reviewer") || "";
    document.getElementById("note").focus();
  }
  document.querySelectorAll('[data-action="approve"]').forEach((b) =>
    b.addEventListener("click", () => ask(Number(b.dataset.take))));
  document.querySelector('[data-action="cancel"]').addEventListener("click", () => dialog.close());
  confirmButton.addEventListener("click", async () => {
    confirmButton.disabled = true; // one click, one decision
    try {
      const by = document.getElementById("reviewer").value.trim();
      if (by) localStorage.setItem("tween-reviewer", by);
      const r = await post("approve", { take: selected, note: document.getElementById("note").value || null,
                                        version: data.version, by: by || null });
      dialog.close();
      say(`approved take ${r.take} by ${r.by}: v${String(r.version).padStart(3, "0")} (${r.layer})`, true);
      document.querySelectorAll('[data-action="approve"]').forEach((b) => b.remove());
      setTimeout(() => location.reload(), 1500);
    } catch (e) {
      dialog.close();
      say(e.message, false);
    } finally {
      confirmButton.disabled = false;
    }
  });
  const publishButton = document.querySelector('[data-action="publish"]');
  if (publishButton) publishButton.addEventListener("click", async () => {
    publishButton.disabled = true;
    try {
      const r = await post("publish", { version: data.version });
      say(`published take ${r.take}: ${r.layer}`, true);
    } catch (e) {
      say(e.message, false);
      publishButton.disabled = false;
    }
  });

  // "Render on the farm": one render-only job for every take without media; the page
  // reloads once the shot's takes all have their turntable.
  async function rendered() {
    const url = `/api/shots/${data.key.split("/").map(encodeURIComponent).join("/")}`;
    const r = await fetch(url, { credentials: "same-origin" });
    return r.ok && (await r.json()).takes.every((t) => t.mp4_url);
  }
  document.querySelectorAll('[data-action="render"]').forEach((b) =>
    b.addEventListener("click", async () => {
      const all = document.querySelectorAll('[data-action="render"]');
      all.forEach((x) => (x.disabled = true)); // one job renders every take
      try {
        const r = await post("render", { version: data.version });
        say(`render job ${r.id.slice(0, 8)}: ${r.state.toLowerCase()}`, true);
        document.dispatchEvent(new Event("tween:jobs"));
        const poll = async () => ((await rendered()) ? location.reload() : setTimeout(poll, 5000));
        setTimeout(poll, 5000);
      } catch (e) {
        say(e.message, false);
        all.forEach((x) => (x.disabled = false));
      }
    }));

  const trackerButton = document.querySelector('[data-action="tracker"]');
  if (trackerButton) trackerButton.addEventListener("click", async () => {
    trackerButton.disabled = true; // one upload per click
    try {
      const r = await post("tracker", { version: data.version });
      say(`sent take ${r.take} to ${r.tracker}: ${r.sequence}/${r.shot}, status ${r.status}`, true);
    } catch (e) {
      say(e.message, false);
      trackerButton.disabled = false;
    }
  });

  document.addEventListener("keydown", (e) => {
    if (e.target.closest("textarea, input[type=text], dialog[open]") || e.ctrlKey || e.metaKey || e.altKey) return;
    if (e.key === " ") { e.preventDefault(); playing() ? pause() : play(); }
    else if (e.key === "ArrowLeft") { e.preventDefault(); step(e.shiftKey ? -10 : -1); }
    else if (e.key === "ArrowRight") { e.preventDefault(); step(e.shiftKey ? 10 : 1); }
    else if (/^[1-9]$/.test(e.key)) {
      const figs = Array.from(document.querySelectorAll("figure.take"));
      const fig = figs[Number(e.key) - 1];
      if (!fig) return;
      figs.forEach((f) => f.classList.toggle("selected", f === fig));
      const b = fig.querySelector('[data-action="approve"]');
      if (b) b.focus();
    }
  });
})();
