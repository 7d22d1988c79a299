// The dashboard's commissioning pages: a drive's parameters (#drive/<id>), its backup and
// restore with the diff, a comparison with another drive of its family, its trips, and finding
// drives on a bus (#bus/<name>). Only the gateway's API routes are used (docs/http-api.md):
// GET /api/drives/{id}/params, GET|PUT /api/drives/{id}/params/{name}, GET .../backup,
// POST .../restore, GET .../trips, GET|POST /api/buses/{bus}/scan. See docs/dashboard.md.
'use strict';

(function () {
  const $ = (sel) => document.querySelector(sel);
  const enc = encodeURIComponent;
  const wb = {
    drive: null, // the drive's id on a drive page
    rows: [], // its parameters: GET /api/drives/{id}/params?read=false, then the values read
    pending: null, // the write waiting for confirmation: { row, value }
    file: null, // the uploaded backup's text
    diff: [], // the rows of the last dry run
    scanTimer: null,
  };

  function client() {
    return window.drivebus;
  }

  // The API's answer as text (the backup file): the token as app.js sends it.
  async function text(method, path, body) {
    const headers = {};
    const t = client().token();
    if (t) headers.Authorization = 'Bearer ' + t;
    if (body !== undefined) headers['Content-Type'] = 'application/json';
    const r = await fetch(path, { method, headers, body, cache: 'no-store' });
    const s = await r.text();
    if (!r.ok) {
      let m = `${r.status}`;
      try {
        const e = JSON.parse(s).error;
        m = `${r.status} ${e.kind}: ${e.message}`;
      } catch (_) { /* not JSON */ }
      throw new Error(m);
    }
    return s;
  }

  function errText(e) {
    return e.status ? `${e.status} ${e.kind}: ${e.message}` : e.message;
  }

  function cell(tr, value, cls) {
    const td = document.createElement('td');
    td.textContent = value == null ? '–' : String(value);
    if (cls) td.className = cls;
    tr.appendChild(td);
    return td;
  }

  function setStatus(sel, msg, kind) {
    const el = $(sel);
    el.textContent = msg || '';
    el.dataset.kind = kind || '';
  }

  // ---------- page switching ----------

  function route() {
    const h = decodeURIComponent(location.hash.slice(1));
    clearInterval(wb.scanTimer);
    if (h.startsWith('drive/')) return openDrive(h.slice(6));
    if (h.startsWith('bus/')) return openBus(h.slice(4));
    document.body.dataset.page = '';
    $('#workbench').hidden = true;
  }

  function show(kind, title, subtitle) {
    document.body.dataset.page = 'workbench';
    $('#workbench').hidden = false;
    $('#wb-drive').hidden = kind !== 'drive';
    $('#wb-bus').hidden = kind !== 'bus';
    $('#wb-title').textContent = title;
    $('#wb-subtitle').textContent = subtitle || '';
    window.scrollTo(0, 0);
  }

  function tab(name) {
    for (const b of document.querySelectorAll('[data-tab]')) b.setAttribute('aria-pressed', String(b.dataset.tab === name));
    for (const p of document.querySelectorAll('[data-pane]')) p.hidden = p.dataset.pane !== name;
    if (name === 'trips') loadTrips();
    if (name === 'compare') fillOthers();
  }

  // ---------- parameters ----------

  async function openDrive(id) {
    wb.drive = id;
    wb.rows = [];
    wb.file = null;
    wb.diff = [];
    show('drive', id, '');
    tab('params');
    $('#wb-param-rows').textContent = '';
    $('#wb-diff-rows').textContent = '';
    $('#wb-compare-rows').textContent = '';
    setStatus('#wb-read-status', 'loading the catalog…');
    setStatus('#wb-backup-status', '');
    setStatus('#wb-apply-status', '');
    try {
      const d = await client().api('GET', `/api/drives/${enc(id)}`);
      $('#wb-subtitle').textContent = `${d.family} · ${d.bus} · address ${d.address}`;
      wb.family = d.family;
      wb.rows = await client().api('GET', `/api/drives/${enc(id)}/params?read=false`);
    } catch (e) {
      setStatus('#wb-read-status', 'cannot read the catalog: ' + errText(e), 'error');
      return;
    }
    const groups = [...new Set(wb.rows.map((r) => r.group))];
    const g = $('#wb-group');
    g.textContent = '';
    for (const name of ['', ...groups]) {
      const o = document.createElement('option');
      o.value = name;
      o.textContent = name || 'all';
      g.appendChild(o);
    }
    if (groups.length) g.value = groups[0];
    setStatus('#wb-read-status', `${wb.rows.length} parameters`);
    $('#wb-readonly').hidden = !!client().token();
    renderParams();
    readGroup();
  }

  function rangeText(r) {
    if (r.choices && r.choices.length) return r.choices.map((c) => `${c.value} ${c.text}`).join(', ');
    return `${r.min}..${r.max}`;
  }

  function visibleRows() {
    const g = $('#wb-group').value;
    const q = $('#wb-search').value.trim().toLowerCase();
    return wb.rows.filter((r) => (!g || r.group === g)
      && (!q || r.name.toLowerCase().includes(q) || r.title.toLowerCase().includes(q)));
  }

  function renderParams() {
    const body = $('#wb-param-rows');
    body.textContent = '';
    const writable = !!client().token();
    for (const r of visibleRows()) {
      const tr = document.createElement('tr');
      tr.dataset.param = r.name;
      if (r.differs) tr.classList.add('differs');
      cell(tr, r.name);
      cell(tr, r.title);
      const v = cell(tr, r.error ? r.error.message : r.text, 'value num');
      v.dataset.field = 'value';
      cell(tr, r.unit);
      cell(tr, rangeText(r));
      cell(tr, r.default_text);
      const act = document.createElement('td');
      act.className = 'wb-edit';
      if (r.access === 'read-write' && writable) {
        const input = document.createElement('input');
        input.dataset.field = 'new';
        input.setAttribute('aria-label', `new value of ${r.name}`);
        input.placeholder = r.value == null ? '' : String(r.value);
        const b = document.createElement('button');
        b.type = 'button';
        b.textContent = 'Edit';
        b.dataset.action = 'edit';
        b.addEventListener('click', () => askWrite(r, input.value.trim()));
        input.addEventListener('keydown', (ev) => { if (ev.key === 'Enter') askWrite(r, input.value.trim()); });
        act.append(input, b);
      } else if (r.access === 'read-only') {
        act.textContent = 'read-only';
        act.classList.add('muted');
      }
      const msg = document.createElement('div');
      msg.className = 'wb-msg';
      msg.dataset.field = 'message';
      act.appendChild(msg);
      tr.appendChild(act);
      body.appendChild(tr);
    }
  }

  function rowEl(name) {
    return document.querySelector(`#wb-param-rows tr[data-param="${CSS.escape(name)}"]`);
  }

  function rowMessage(name, msg, kind) {
    const tr = rowEl(name);
    if (!tr) return;
    const m = tr.querySelector('[data-field=message]');
    m.textContent = msg;
    m.dataset.kind = kind;
  }

  async function readOne(r) {
    const id = wb.drive;
    try {
      const v = await client().api('GET', `/api/drives/${enc(id)}/params/${enc(r.name)}`);
      Object.assign(r, { raw: v.raw, value: v.value, text: v.text, differs: v.value !== r.default, error: null });
    } catch (e) {
      r.error = { kind: e.kind, message: errText(e) };
    }
  }

  async function readGroup() {
    const rows = visibleRows();
    const bar = $('#wb-read-progress');
    bar.max = Math.max(rows.length, 1);
    bar.value = 0;
    $('#wb-read').disabled = true;
    let failed = 0;
    for (const r of rows) {
      await readOne(r);
      if (r.error) failed++;
      bar.value += 1;
      setStatus('#wb-read-status', `read ${bar.value} of ${rows.length}`);
    }
    $('#wb-read').disabled = false;
    setStatus('#wb-read-status', `read ${rows.length} parameters` + (failed ? `, ${failed} not read` : ''), failed ? 'error' : 'ok');
    renderParams();
  }

  function askWrite(r, value) {
    if (!value) {
      rowMessage(r.name, 'type the new value first', 'error');
      return;
    }
    wb.pending = { r, value };
    const old = r.text == null ? '(not read)' : r.text;
    $('#wb-confirm-text').textContent = `${r.name} ${r.title}: ${old} → ${value} ${r.unit}`.trim();
    $('#wb-confirm').hidden = false;
  }

  async function confirmWrite() {
    const p = wb.pending;
    $('#wb-confirm').hidden = true;
    wb.pending = null;
    if (!p) return;
    const { r, value } = p;
    rowMessage(r.name, 'writing…', '');
    try {
      await client().api('PUT', `/api/drives/${enc(wb.drive)}/params/${enc(r.name)}`, { value, eeprom: r.storage === 'eeprom' });
      await readOne(r);
      renderParams();
      rowMessage(r.name, `written: ${r.text}`, 'ok');
    } catch (e) {
      if (e.status === 401) client().askToken('Writing needs a write token.', () => askWrite(r, value));
      rowMessage(r.name, 'not written: ' + errText(e), 'error');
    }
  }

  // ---------- backup and restore ----------

  async function download() {
    setStatus('#wb-backup-status', 'reading the drive…');
    try {
      const file = await text('GET', `/api/drives/${enc(wb.drive)}/backup`);
      const a = document.createElement('a');
      a.href = URL.createObjectURL(new Blob([file], { type: 'application/json' }));
      a.download = `${wb.drive}.json`;
      document.body.appendChild(a);
      a.click();
      a.remove();
      wb.lastBackup = file;
      setStatus('#wb-backup-status', `backup of ${Object.keys(JSON.parse(file).params).length} parameters downloaded as ${wb.drive}.json`, 'ok');
    } catch (e) {
      setStatus('#wb-backup-status', 'no backup: ' + e.message, 'error');
    }
  }

  async function loadFile(f) {
    wb.file = await f.text();
    await showDiff();
  }

  async function showDiff() {
    $('#wb-diff-rows').textContent = '';
    $('#wb-apply').disabled = true;
    setStatus('#wb-backup-status', 'comparing with the drive…');
    let res;
    try {
      res = JSON.parse(await text('POST', `/api/drives/${enc(wb.drive)}/restore?dry_run=true&include_comm=true`, wb.file));
    } catch (e) {
      setStatus('#wb-backup-status', 'cannot compare: ' + e.message, 'error');
      return;
    }
    wb.diff = res.rows;
    if (!res.rows.length) {
      setStatus('#wb-backup-status', 'No difference: the drive holds the file\'s values.', 'ok');
      return;
    }
    setStatus('#wb-backup-status', `${res.rows.length} ${res.rows.length === 1 ? 'parameter differs' : 'parameters differ'}` +
      (res.rows.some((r) => r.comm) ? ' (communication settings unticked: tick them to restore them too)' : ''));
    for (const r of res.rows) {
      const tr = document.createElement('tr');
      tr.dataset.param = r.name;
      const td = document.createElement('td');
      const box = document.createElement('input');
      box.type = 'checkbox';
      box.checked = !r.comm;
      box.setAttribute('aria-label', `apply ${r.name}`);
      td.appendChild(box);
      tr.appendChild(td);
      cell(tr, r.name + (r.comm ? ' (communication)' : ''));
      cell(tr, r.title);
      cell(tr, r.drive.value || r.drive.raw);
      cell(tr, r.file.value || r.file.raw);
      const res = cell(tr, '', 'wb-msg');
      res.dataset.field = 'result';
      $('#wb-diff-rows').appendChild(tr);
    }
    $('#wb-apply').disabled = false;
  }

  async function applySelected() {
    const rows = [...document.querySelectorAll('#wb-diff-rows tr')].filter((tr) => tr.querySelector('input').checked);
    const bar = $('#wb-apply-progress');
    bar.max = Math.max(rows.length, 1);
    bar.value = 0;
    $('#wb-apply').disabled = true;
    let ok = 0;
    for (const tr of rows) {
      const name = tr.dataset.param;
      const r = wb.diff.find((x) => x.name === name);
      const out = tr.querySelector('[data-field=result]');
      try {
        const q = `only=${enc(name)}${r && r.comm ? '&include_comm=true' : ''}`;
        const res = JSON.parse(await text('POST', `/api/drives/${enc(wb.drive)}/restore?${q}`, wb.file));
        const row = res.rows.find((x) => x.name === name);
        if (row && row.result === 'ok') {
          ok++;
          out.textContent = 'ok';
          out.dataset.kind = 'ok';
        } else {
          out.textContent = row && row.error ? row.error.message : 'not written';
          out.dataset.kind = 'error';
        }
      } catch (e) {
        out.textContent = e.message;
        out.dataset.kind = 'error';
      }
      bar.value += 1;
    }
    setStatus('#wb-apply-status', `${ok} of ${rows.length} written`, ok === rows.length ? 'ok' : 'error');
  }

  // ---------- compare ----------

  async function fillOthers() {
    const sel = $('#wb-other');
    if (sel.dataset.drive === wb.drive) return;
    sel.dataset.drive = wb.drive;
    sel.textContent = '';
    try {
      const drives = await client().api('GET', '/api/drives');
      for (const d of drives.filter((x) => x.family === wb.family && x.id !== wb.drive)) {
        const o = document.createElement('option');
        o.value = d.id;
        o.textContent = d.id;
        sel.appendChild(o);
      }
    } catch (e) {
      setStatus('#wb-compare-status', errText(e), 'error');
    }
  }

  async function compare() {
    const other = $('#wb-other').value;
    if (!other) {
      setStatus('#wb-compare-status', `no other ${wb.family} drive to compare with`, 'error');
      return;
    }
    const bar = $('#wb-compare-progress');
    bar.value = 0;
    $('#wb-compare-rows').textContent = '';
    $('#wb-compare-a').textContent = wb.drive;
    $('#wb-compare-b').textContent = other;
    try {
      const a = JSON.parse(await text('GET', `/api/drives/${enc(wb.drive)}/backup`));
      bar.value = 1;
      const b = JSON.parse(await text('GET', `/api/drives/${enc(other)}/backup`));
      bar.value = 2;
      let differ = 0;
      for (const name of Object.keys(a.params)) {
        const x = a.params[name];
        const y = b.params[name];
        const tr = document.createElement('tr');
        tr.dataset.param = name;
        if (!y || x.raw !== y.raw) {
          tr.classList.add('differ');
          differ++;
        }
        cell(tr, name);
        cell(tr, x.value);
        cell(tr, y ? y.value : '–');
        $('#wb-compare-rows').appendChild(tr);
      }
      setStatus('#wb-compare-status', `${differ} of ${Object.keys(a.params).length} settings differ`);
    } catch (e) {
      setStatus('#wb-compare-status', e.message, 'error');
    }
  }

  // ---------- trips ----------

  function snapshot(s) {
    if (!s) return '–';
    const f = (v, u) => (typeof v === 'number' ? `${v.toFixed(2)} ${u}` : '–');
    return `${s.running ? 'running' : 'stopped'} ${f(s.output_hz, 'Hz')} ${f(s.current_a, 'A')}`;
  }

  async function loadTrips() {
    $('#wb-trips-rows').textContent = '';
    $('#wb-trip-events').textContent = '';
    $('#wb-trips-current').textContent = 'reading…';
    try {
      const t = await client().api('GET', `/api/drives/${enc(wb.drive)}/trips`);
      $('#wb-trips-current').textContent = t.current ? `In force: ${t.current.code} (${t.current.text})` : 'No trip in force.';
      $('#wb-trips-source').textContent = 'From ' + t.source;
      for (const e of t.history) {
        const tr = document.createElement('tr');
        cell(tr, e.index);
        cell(tr, e.code);
        cell(tr, e.text);
        cell(tr, e.output_hz, 'num');
        cell(tr, e.current_a, 'num');
        $('#wb-trips-rows').appendChild(tr);
      }
      for (const e of t.events) {
        const tr = document.createElement('tr');
        cell(tr, new Date(e.time_ms).toLocaleString());
        cell(tr, e.detail ? `${e.detail.code} ${e.detail.text}` : '');
        cell(tr, snapshot(e.detail && e.detail.before));
        cell(tr, snapshot(e.detail && e.detail.at_trip));
        $('#wb-trip-events').appendChild(tr);
      }
    } catch (e) {
      $('#wb-trips-current').textContent = 'Cannot read the trips: ' + errText(e);
    }
  }

  // ---------- finding drives on a bus ----------

  function showScan(s) {
    const bar = $('#wb-scan-progress');
    bar.max = Math.max(s.total, 1);
    bar.value = s.tried;
    setStatus('#wb-scan-status', s.running ? `tried ${s.tried} of ${s.total} (${s.families.join(', ')})`
      : `done: ${s.found.length} found at ${s.addresses.length} addresses`, s.running ? '' : 'ok');
    const body = $('#wb-found-rows');
    body.textContent = '';
    for (const f of s.found) {
      const tr = document.createElement('tr');
      tr.dataset.address = f.address;
      cell(tr, f.address, 'num');
      cell(tr, f.family);
      cell(tr, f.model);
      cell(tr, f.state);
      cell(tr, f.configured || 'not configured');
      body.appendChild(tr);
    }
    $('#wb-config').textContent = s.config;
    $('#wb-scan').disabled = s.running;
  }

  async function openBus(name) {
    wb.bus = name;
    show('bus', name, 'find drives');
    $('#wb-found-rows').textContent = '';
    $('#wb-config').textContent = '';
    setStatus('#wb-scan-status', '');
    try {
      const s = await client().api('GET', `/api/buses/${enc(name)}/scan`);
      showScan(s);
      if (s.running) follow();
    } catch (e) {
      if (e.kind !== 'not_scanned') setStatus('#wb-scan-status', errText(e), 'error');
    }
  }

  function follow() {
    clearInterval(wb.scanTimer);
    wb.scanTimer = setInterval(async () => {
      try {
        const s = await client().api('GET', `/api/buses/${enc(wb.bus)}/scan`);
        showScan(s);
        if (!s.running) clearInterval(wb.scanTimer);
      } catch (e) {
        setStatus('#wb-scan-status', errText(e), 'error');
        clearInterval(wb.scanTimer);
      }
    }, 300);
  }

  async function startScan() {
    const a = $('#wb-addresses').value.trim();
    try {
      showScan(await client().api('POST', `/api/buses/${enc(wb.bus)}/scan?addresses=${enc(a)}`));
      follow();
    } catch (e) {
      if (e.status === 401) client().askToken('Finding drives needs a write token.', startScan);
      setStatus('#wb-scan-status', 'not started: ' + errText(e), 'error');
    }
  }

  function init() {
    for (const b of document.querySelectorAll('[data-tab]')) b.addEventListener('click', () => tab(b.dataset.tab));
    $('#wb-group').addEventListener('change', renderParams);
    $('#wb-search').addEventListener('input', renderParams);
    $('#wb-read').addEventListener('click', readGroup);
    $('#wb-confirm-yes').addEventListener('click', confirmWrite);
    $('#wb-confirm-no').addEventListener('click', () => { $('#wb-confirm').hidden = true; wb.pending = null; });
    $('#wb-download').addEventListener('click', download);
    $('#wb-file').addEventListener('change', (ev) => { if (ev.target.files[0]) loadFile(ev.target.files[0]); });
    $('#wb-apply').addEventListener('click', applySelected);
    $('#wb-compare-go').addEventListener('click', compare);
    $('#wb-scan').addEventListener('click', startScan);
    window.addEventListener('hashchange', route);
    // Tests and scripts may hand the page a backup's text instead of a file picker.
    window.drivebusWorkbench = { restoreText: (t) => { wb.file = t; return showDiff(); }, lastBackup: () => wb.lastBackup };
    route();
  }

  if (document.readyState === 'loading') document.addEventListener('DOMContentLoaded', init);
  else init();
})();
