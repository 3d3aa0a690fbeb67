// Attune console: the little the server-rendered pages need from the browser.
// No inline scripts (the pages' Content-Security-Policy forbids them): everything starts here.
"use strict";

// Selects marked data-autosubmit reload the page as soon as they change.
function autosubmit() {
  document.querySelectorAll("form[data-autosubmit] select").forEach((select) => {
    select.addEventListener("change", () => select.form.submit());
  });
}

// The retention form: typing a number of days chooses "removed once older than" (without a
// script the choice is made by hand; the server refuses neither way round in silence).
function windowForm() {
  const days = document.querySelector("#window-form #days");
  const choice = document.querySelector("#window-form #keep-days");
  if (!days || !choice) return;
  days.addEventListener("input", () => { choice.checked = true; });
}

// Episode rows load their trace (an HTML fragment rendered by the server) when first opened.
function traces() {
  document.querySelectorAll("details[data-trace-url]").forEach((details) => {
    details.addEventListener("toggle", async () => {
      if (!details.open || details.dataset.loaded) return;
      details.dataset.loaded = "loading";
      const box = details.querySelector(".trace");
      try {
        const response = await fetch(details.dataset.traceUrl, {
          credentials: "same-origin", headers: { Accept: "text/html" },
        });
        if (!response.ok) throw new Error(`${response.status} ${response.statusText}`);
        box.innerHTML = await response.text();  // our own escaped template, same origin
        details.dataset.loaded = "yes";
      } catch (err) {
        box.textContent = `The trace could not be loaded (${err.message}); reload the page.`;
        delete details.dataset.loaded;
      }
    });
  });
}

// The cumulative reward curve (uPlot, bundled under /admin/static/vendor/uplot/). The x axis
// counts whole episodes (1 = the first); the caption under the chart always says where the
// curve ends, and the value under the pointer while it moves over the chart.
const EPISODE_STEPS = [1, 2, 5, 10, 20, 50, 100, 200, 500, 1000, 2000, 5000, 10000, 20000,
  50000, 100000, 200000, 500000, 1000000];

function rewardChart() {
  const box = document.getElementById("reward-chart");
  const source = document.getElementById("reward-data");
  if (!box || !source || typeof uPlot === "undefined") return;
  const data = JSON.parse(source.textContent);
  const xs = data.x.map((i) => i + 1);  // episode numbers, as the episodes list shows them
  const cursorText = document.getElementById("reward-cursor");
  const size = () => ({ width: Math.max(240, box.clientWidth), height: 260 });
  const opts = {
    ...size(),
    legend: { show: false },  // the caption below says it without hovering
    cursor: { drag: { x: true, y: false } },
    scales: { x: { time: false } },
    axes: [
      { label: "episode", size: 40, incrs: EPISODE_STEPS,
        values: (u, ticks) => {
          box.dataset.xTicks = ticks.join(" ");  // what the axis shows, for the tests
          return ticks.map((t) => (Number.isInteger(t) ? String(t) : ""));
        } },
      { label: "cumulative reward", size: 60 },
    ],
    series: [
      { label: "episode" },
      { label: "reward", stroke: "#1f5fa8", width: 2, fill: "rgba(31,95,168,0.08)" },
    ],
    hooks: {
      setCursor: [(u) => {
        if (!cursorText) return;
        const i = u.cursor.idx;
        cursorText.textContent = i == null ? ""
          : ` · at episode ${u.data[0][i]}: ${u.data[1][i].toFixed(1)}`;
      }],
    },
  };
  const chart = new uPlot(opts, [xs, data.y], box);
  box.dataset.ready = "yes";
  let pending = 0;
  window.addEventListener("resize", () => {
    cancelAnimationFrame(pending);
    pending = requestAnimationFrame(() => chart.setSize(size()));
  });
}

// The correction form: the choices offered are the chosen service's; "stay quiet" needs no
// service.
function correctionForm() {
  const form = document.getElementById("correction-form");
  if (!form) return;
  const service = form.querySelector("#c-service");
  const detail = form.querySelector("#c-detail");
  const what = form.querySelector("#what");
  const update = () => {
    const kind = form.querySelector("input[name=kind]:checked");
    const quiet = kind && kind.value === "quiet";
    service.disabled = quiet;
    detail.disabled = quiet;
    what.classList.toggle("off", quiet);
    detail.querySelectorAll("optgroup").forEach((group) => {
      const mine = group.dataset.service === service.value;
      group.hidden = !mine;
      group.disabled = !mine;
    });
    const picked = detail.selectedOptions[0];
    if (picked && picked.dataset.service && picked.dataset.service !== service.value) {
      detail.value = "";
    }
    // "Any" is for "should not offer" only: a preference names one choice.
    const any = detail.querySelector("#c-detail-any");
    const prefers = kind && kind.value === "prefers";
    if (any) any.disabled = prefers;
    if (prefers && detail.value === "") {
      const mine = `optgroup[data-service="${CSS.escape(service.value)}"] option`;
      const first = detail.querySelector(mine);
      if (first) detail.value = first.value;
    }
  };
  form.querySelectorAll("input[name=kind]").forEach((r) => r.addEventListener("change", update));
  service.addEventListener("change", update);
  update();
}

// The profile's boxes: the one under the pointer or the keyboard's focus is said as a sentence
// under the grid (screen readers read the same sentence inside the box).
function profileSummaries() {
  const line = document.getElementById("cell-summary");
  if (!line) return;
  const initial = line.textContent;
  document.querySelectorAll("#profile td.pcell a[data-summary]").forEach((link) => {
    const show = () => { line.textContent = link.dataset.summary; };
    link.addEventListener("mouseenter", show);
    link.addEventListener("focus", show);
  });
  const grid = document.getElementById("profile");
  if (grid) grid.addEventListener("mouseleave", () => { line.textContent = initial; });
}

// A chosen box of the profile: its evidence section takes the focus, so that a keyboard user
// lands on it.
function evidenceFocus() {
  const evidence = document.getElementById("evidence");
  if (evidence && window.location.hash === "#evidence") evidence.focus({ preventScroll: false });
}

// What if: a page that follows an evaluation under way (an element with data-poll-url and
// data-active="true") fetches that element again every two seconds (the page itself, or the
// fragment its address names) and puts it in place; once the evaluation has ended, a page that
// shows its result (data-reload-when-done) reloads to show it. Without a script, the pages say
// to reload them.
const POLL_MS = 2000;

async function poll(box) {
  let fresh = null;
  try {
    const response = await fetch(box.dataset.pollUrl, {
      credentials: "same-origin", headers: { Accept: "text/html" },
    });
    if (response.status >= 400 && response.status < 500) return;  // signed out, not allowed
    if (!response.ok) throw new Error(`${response.status} ${response.statusText}`);
    const doc = new DOMParser().parseFromString(await response.text(), "text/html");
    fresh = doc.getElementById(box.id);
  } catch (err) {
    setTimeout(() => poll(box), POLL_MS * 3);  // the service busy or restarting: later
    return;
  }
  if (!fresh) return;
  if (fresh.dataset.active !== "true" && box.dataset.reloadWhenDone) {
    window.location.reload();
    return;
  }
  const adopted = document.importNode(fresh, true);
  box.replaceWith(adopted);
  if (adopted.dataset.active === "true") setTimeout(() => poll(adopted), POLL_MS);
}

function followEvaluations() {
  document.querySelectorAll("[data-poll-url]").forEach((box) => {
    if (box.dataset.active === "true") setTimeout(() => poll(box), POLL_MS);
  });
}

document.addEventListener("DOMContentLoaded", () => {
  autosubmit();
  windowForm();
  traces();
  rewardChart();
  correctionForm();
  profileSummaries();
  evidenceFocus();
  followEvaluations();
});
