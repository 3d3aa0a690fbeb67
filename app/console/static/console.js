// Attune console: the little the server-rendered pages need from the browser.
// No inline scripts (the pages' Content-Security-Policy forbids them): everything starts here.
"use strict";

// Selects marked data-autosubmit reload the page as soon as they change.
function autosubmit() {
  document.querySelectorAll("form[data-autosubmit] select").forEach((select) => {
    select.addEventListener("change", () => select.form.submit());
  });
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

// The cumulative reward curve (uPlot, bundled under /admin/static/vendor/uplot/).
function rewardChart() {
  const box = document.getElementById("reward-chart");
  const source = document.getElementById("reward-data");
  if (!box || !source || typeof uPlot === "undefined") return;
  const data = JSON.parse(source.textContent);
  const size = () => ({ width: Math.max(240, box.clientWidth), height: 260 });
  const opts = {
    ...size(),
    legend: { show: true },
    cursor: { drag: { x: true, y: false } },
    scales: { x: { time: false } },
    axes: [
      { label: "episode", size: 40 },
      { label: "cumulative reward", size: 60 },
    ],
    series: [
      { label: "episode" },
      { label: "reward", stroke: "#1f5fa8", width: 2, fill: "rgba(31,95,168,0.08)" },
    ],
  };
  const chart = new uPlot(opts, [data.x, data.y], box);
  box.dataset.ready = "yes";
  let pending = 0;
  window.addEventListener("resize", () => {
    cancelAnimationFrame(pending);
    pending = requestAnimationFrame(() => chart.setSize(size()));
  });
}

document.addEventListener("DOMContentLoaded", () => {
  autosubmit();
  traces();
  rewardChart();
});
