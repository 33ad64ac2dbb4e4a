"use strict";
// Sortable tables, filters and plots of the report page (no library besides Plotly, no network).
(function () {
  // ---------------------------------------------------------------- sorting
  // a click sorts ascending, a second descending, a third restores the table's order; numbers
  // numerically (data-value), missing values ("") last in both directions; ties keep the order
  function sortKey(cell, type) {
    var v = cell ? cell.getAttribute("data-value") : "";
    if (v === null) { v = cell.textContent.trim(); }
    if (v === "") { return null; }
    if (type === "number") {
      var x = parseFloat(v);
      return isNaN(x) ? null : x;
    }
    return v;
  }

  function sortTable(table, col, th) {
    var type = th.getAttribute("data-type") || "text";
    var state = th.getAttribute("aria-sort");
    var next = state === "ascending" ? "descending" : state === "descending" ? "none" : "ascending";
    Array.prototype.forEach.call(table.tHead.rows[0].cells, function (h) { h.setAttribute("aria-sort", "none"); });
    th.setAttribute("aria-sort", next);
    var body = table.tBodies[0];
    var rows = Array.prototype.slice.call(body.rows);
    rows.sort(function (a, b) {
      var ia = parseInt(a.getAttribute("data-order"), 10), ib = parseInt(b.getAttribute("data-order"), 10);
      if (next === "none") { return ia - ib; }
      var ka = sortKey(a.cells[col], type), kb = sortKey(b.cells[col], type);
      if (ka === null && kb === null) { return ia - ib; }
      if (ka === null) { return 1; }
      if (kb === null) { return -1; }
      var c = type === "number" ? ka - kb : String(ka).localeCompare(String(kb), undefined, { numeric: true });
      if (c === 0) { return ia - ib; }
      return next === "ascending" ? c : -c;
    });
    rows.forEach(function (r) { body.appendChild(r); });
  }

  function initSorting() {
    document.querySelectorAll("table.sortable").forEach(function (table) {
      Array.prototype.forEach.call(table.tHead.rows[0].cells, function (th, col) {
        th.addEventListener("click", function () { sortTable(table, col, th); });
        th.addEventListener("keydown", function (e) {
          if (e.key === "Enter" || e.key === " ") { e.preventDefault(); sortTable(table, col, th); }
        });
      });
    });
  }

  // ---------------------------------------------------------------- filters
  // an element with data-scenes / data-objects / data-methods (JSON lists) is hidden when none of
  // its values of one of them is checked
  var DIMENSIONS = ["scenes", "objects", "methods"];

  function checked() {
    var sel = {};
    DIMENSIONS.forEach(function (d) {
      sel[d] = {};
      document.querySelectorAll('#filters input[data-filter="' + d + '"]').forEach(function (box) {
        if (box.checked) { sel[d][box.value] = true; }
      });
    });
    return sel;
  }

  function applyFilters() {
    var sel = checked();
    var selector = DIMENSIONS.map(function (d) { return "[data-" + d + "]"; }).join(",");
    document.querySelectorAll(selector).forEach(function (el) {
      var visible = DIMENSIONS.every(function (d) {
        var raw = el.getAttribute("data-" + d);
        if (raw === null) { return true; }
        var values = JSON.parse(raw);
        return values.length === 0 || values.some(function (v) { return sel[d][v]; });
      });
      el.classList.toggle("filtered-out", !visible);
    });
    var status = document.getElementById("filter-status");
    if (status) {
      var rows = document.querySelectorAll("table.gallery tbody tr");
      var shown = Array.prototype.filter.call(rows, function (r) { return !r.classList.contains("filtered-out"); });
      status.textContent = shown.length + " of " + rows.length + " gallery rows shown";
    }
  }

  function initFilters() {
    document.querySelectorAll("#filters input[data-filter]").forEach(function (box) {
      box.addEventListener("change", applyFilters);
    });
    document.querySelectorAll("#filters button[data-all]").forEach(function (button) {
      button.addEventListener("click", function () {
        var on = button.getAttribute("data-all") === "true";
        document.querySelectorAll('#filters input[data-filter="' + button.getAttribute("data-for") + '"]')
          .forEach(function (box) { box.checked = on; });
        applyFilters();
      });
    });
    applyFilters();
  }

  // ---------------------------------------------------------------- plots
  function initPlots() {
    document.querySelectorAll("div.plot[data-spec]").forEach(function (div) {
      if (typeof Plotly === "undefined") {
        div.classList.add("plot-missing");
        div.textContent = "Plotly did not load: plotly.min.js should sit beside this page.";
        return;
      }
      var spec = JSON.parse(document.getElementById(div.getAttribute("data-spec")).textContent);
      Plotly.newPlot(div, spec.data, spec.layout, { responsive: true, displaylogo: false });
    });
  }

  document.addEventListener("DOMContentLoaded", function () {
    initSorting();
    initFilters();
    initPlots();
  });
})();
