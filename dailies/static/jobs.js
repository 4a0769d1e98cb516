// The farm's jobs for these shots (or this shot): state, stage, reason, and cancel.
"use strict";
(function () {
  const box = document.getElementById("jobs");
  if (!box) return;
  const csrf = document.querySelector('meta[name="csrf-token"]').content;
  const shot = box.dataset.shot;
  const url = "/api/jobs" + (shot ? `?shot=${encodeURIComponent(shot)}` : "");
  const cell = (text, cls) => {
    const td = document.createElement("td");
    td.textContent = text == null ? "" : String(text);
    if (cls) td.className = cls;
    return td;
  };
  async function refresh() {
    let data;
    try {
      const r = await fetch(url, { credentials: "same-origin" });
      data = await r.json();
      if (!r.ok) throw new Error(data.detail || r.statusText);
    } catch (e) {
      box.querySelector(".note").textContent = `farm: ${e.message}`;
      return;
    }
    box.querySelector(".note").textContent = data.note || (data.jobs.length ? "" : `no jobs waiting or failed on ${data.farm}`);
    const body = box.querySelector("tbody");
    body.replaceChildren(...data.jobs.map((j) => {
      const tr = document.createElement("tr");
      tr.dataset.job = j.id;
      const when = j.submitted ? new Date(j.submitted * 1000).toLocaleString() : "";
      tr.append(cell(j.shot.split("/").pop(), "path"), cell(j.id.slice(0, 8)), cell(j.state.toLowerCase(), `state state-${j.state}`),
                cell(j.stage ? `${j.stage} (${j.done}/${j.total})` : `${j.done}/${j.total}`), cell(j.error || (j.lost ? `worker ${j.lost.worker} silent ${j.lost.silent_s} s` : "")), cell(when));
      const act = document.createElement("td");
      if (["QUEUED", "RUNNING"].includes(j.state)) {
        const b = document.createElement("button");
        b.type = "button";
        b.dataset.action = "cancel-job";
        b.dataset.job = j.id;
        b.textContent = "Cancel";
        b.addEventListener("click", async () => {
          b.disabled = true;
          const r = await fetch(`/api/jobs/${j.id}/cancel`, { method: "POST", headers: { "X-CSRF-Token": csrf }, credentials: "same-origin" });
          const out = await r.json().catch(() => ({}));
          box.querySelector(".note").textContent = r.ok ? `job ${j.id.slice(0, 8)}: ${out.state.toLowerCase()}` : out.detail;
          refresh();
        });
        act.append(b);
      }
      tr.append(act);
      return tr;
    }));
    if (data.jobs.some((j) => ["QUEUED", "RUNNING", "CANCELLING"].includes(j.state))) setTimeout(refresh, 5000);
  }
  refresh();
  document.addEventListener("tween:jobs", refresh); // a job submitted from the page
})();
