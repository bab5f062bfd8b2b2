// Sorting and filtering of the report's sample lists, in the page: no server, no network, no library.
//
// A <table class="listing"> opts in. Its header cells say how: data-type="number" sorts by the cells' data-value
// (text otherwise); data-filter="choice" adds a drop-down of the column's values (a cell's data-values holds several,
// separated by "|", e.g. a sample's tags); data-filter="range" adds "from" and "to" number boxes. A click on a header
// sorts by it, a second click reverses. Rows that a filter hides get the hidden attribute, so a test sees them go.
"use strict";

function cellValues(cell) {
  const listed = cell.getAttribute("data-values");
  return listed === null ? [cell.textContent.trim()] : listed.split("|").filter((value) => value !== "");
}

function cellNumber(cell) {
  const value = parseFloat(cell.getAttribute("data-value"));
  return Number.isNaN(value) ? null : value;
}

function sortRows(table, column, type, descending) {
  const body = table.tBodies[0];
  const rows = Array.from(body.rows);
  const key = (row) => (type === "number" ? cellNumber(row.cells[column]) : row.cells[column].textContent.trim());
  rows.sort((a, b) => {
    const x = key(a);
    const y = key(b);
    if (x === y) return 0;
    if (x === null) return 1; // a missing number goes last either way
    if (y === null) return -1;
    const order = type === "number" ? x - y : String(x).localeCompare(String(y));
    return descending ? -order : order;
  });
  rows.forEach((row) => body.appendChild(row));
}

function applyFilters(table, filters) {
  for (const row of table.tBodies[0].rows) {
    const shown = filters.every((filter) => filter.keeps(row.cells[filter.column]));
    row.hidden = !shown;
  }
}

function choiceFilter(table, column, header, bar, filters) {
  const values = new Set();
  for (const row of table.tBodies[0].rows) cellValues(row.cells[column]).forEach((value) => values.add(value));
  const select = document.createElement("select");
  select.setAttribute("data-filter-for", header.textContent.trim());
  select.add(new Option(`${header.textContent.trim()}: all`, ""));
  Array.from(values).sort().forEach((value) => select.add(new Option(value, value)));
  filters.push({ column, keeps: (cell) => select.value === "" || cellValues(cell).includes(select.value) });
  select.addEventListener("change", () => applyFilters(table, filters));
  bar.appendChild(select);
}

function rangeFilter(table, column, header, bar, filters) {
  const bounds = ["from", "to"].map((side) => {
    const input = document.createElement("input");
    input.type = "number";
    input.step = "any";
    input.placeholder = `${header.textContent.trim()} ${side}`;
    input.setAttribute("data-filter-for", `${header.textContent.trim()} ${side}`);
    input.addEventListener("input", () => applyFilters(table, filters));
    bar.appendChild(input);
    return input;
  });
  filters.push({
    column,
    keeps: (cell) => {
      const value = cellNumber(cell);
      const [low, high] = bounds.map((input) => (input.value === "" ? null : parseFloat(input.value)));
      return (low === null || (value !== null && value >= low)) && (high === null || (value !== null && value <= high));
    },
  });
}

function makeListing(table) {
  const headers = Array.from(table.tHead.rows[0].cells);
  const bar = document.createElement("div");
  bar.className = "filters";
  const filters = [];
  headers.forEach((header, column) => {
    const type = header.getAttribute("data-type") || "text";
    header.classList.add("sortable");
    header.title = "click to sort";
    header.addEventListener("click", () => {
      const descending = header.getAttribute("aria-sort") === "ascending";
      headers.forEach((other) => other.removeAttribute("aria-sort"));
      header.setAttribute("aria-sort", descending ? "descending" : "ascending");
      sortRows(table, column, type, descending);
    });
    const filter = header.getAttribute("data-filter");
    if (filter === "choice") choiceFilter(table, column, header, bar, filters);
    if (filter === "range") rangeFilter(table, column, header, bar, filters);
  });
  if (filters.length) table.parentNode.insertBefore(bar, table);
}

document.addEventListener("DOMContentLoaded", () => document.querySelectorAll("table.listing").forEach(makeListing));
