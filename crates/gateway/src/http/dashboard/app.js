// The drivebus dashboard: plain JavaScript, no library, served by the gateway itself.
// It reads GET /api/buses, /api/drives and /api/events, follows GET /api/stream (server-sent
// events read through fetch so that a token can be sent), and sends commands with the token kept
// in sessionStorage. See docs/dashboard.md.
'use strict';

(function () {
  const TOKEN_KEY = 'drivebus.token';
  const TREND_SPAN_MS = 10 * 60 * 1000;
  const MAX_EVENTS = 300;

  const $ = (sel, root) => (root || document).querySelector(sel);
  const field = (root, name) => root.querySelector(`[data-field="${name}"]`);

  const VIEW_KEY = 'drivebus.view';
  // Above this many drives the page opens on the table: a card per drive would be a long scroll.
  const TABLE_FROM = 60;

  const state = {
    // id -> { view, receivedAt, tile (made when the cards are first shown), row, samples: [{t, hz, a}],
    //         trendOpen, history }
    drives: new Map(),
    buses: new Map(), // name -> { view, el }
    events: [],
    eventIds: new Set(),
    streaming: false,
    pollTimer: null,
    pendingAfterToken: null,
    view: null, // 'cards' or 'table'
    dirty: new Set(), // drives whose values changed since the page last showed them
    flushTimer: null,
    denseStale: true, // the table's rows must be filtered and sorted again
    sort: { key: 'id', dir: 1 },
  };

  // ---------- token ----------

  function token() {
    try {
      return sessionStorage.getItem(TOKEN_KEY) || '';
    } catch (_) {
      return state.memoryToken || '';
    }
  }

  function setToken(t) {
    try {
      if (t) sessionStorage.setItem(TOKEN_KEY, t);
      else sessionStorage.removeItem(TOKEN_KEY);
    } catch (_) {
      state.memoryToken = t;
    }
    updateTokenButton();
  }

  function updateTokenButton() {
    const b = $('#token-button');
    b.textContent = token() ? 'Token ✓' : 'Token';
    b.title = token() ? 'a token is set for this tab: click to change or forget it' : 'enter a token';
  }

  function askToken(prompt, then) {
    const dlg = $('#token-dialog');
    $('#token-prompt').textContent = prompt;
    state.pendingAfterToken = then || null;
    dlg.hidden = false;
    const input = $('#token-input');
    input.value = '';
    input.focus();
    dlg.scrollIntoView({ block: 'nearest' });
  }

  function closeTokenDialog() {
    $('#token-dialog').hidden = true;
    state.pendingAfterToken = null;
  }

  function wireTokenDialog() {
    $('#token-dialog').addEventListener('submit', (ev) => {
      ev.preventDefault();
      const t = $('#token-input').value.trim();
      if (!t) {
        $('#token-prompt').textContent = 'Enter a token (drivebus serve --demo prints one), or Cancel.';
        return;
      }
      setToken(t);
      const then = state.pendingAfterToken;
      closeTokenDialog();
      if (then) then();
    });
    $('#token-cancel').addEventListener('click', closeTokenDialog);
    $('#token-forget').addEventListener('click', () => {
      setToken('');
      closeTokenDialog();
      notice('The token is forgotten: commands will ask for one again.', 'info');
    });
    $('#token-button').addEventListener('click', () => {
      askToken(token() ? 'A token is set for this tab. Enter another to replace it, or Forget it.'
        : 'Enter a token: a write token sends commands, a read token only reads.');
    });
  }

  // ---------- HTTP ----------

  class ApiError extends Error {
    constructor(status, kind, message) {
      super(message);
      this.status = status;
      this.kind = kind;
    }
  }

  async function api(method, path, body) {
    const headers = { Accept: 'application/json' };
    const t = token();
    if (t) headers.Authorization = 'Bearer ' + t;
    const init = { method, headers, cache: 'no-store' };
    if (body !== undefined) {
      headers['Content-Type'] = 'application/json';
      init.body = JSON.stringify(body);
    }
    let r;
    try {
      r = await fetch(path, init);
    } catch (e) {
      throw new ApiError(0, 'network', 'the gateway did not answer (' + e.message + ')');
    }
    const text = await r.text();
    let data = null;
    try {
      data = text ? JSON.parse(text) : null;
    } catch (_) {
      data = null;
    }
    if (!r.ok) {
      const err = data && data.error;
      const message = err && err.message ? err.message : `${r.status} ${r.statusText || 'error'}`;
      throw new ApiError(r.status, err && err.kind ? err.kind : 'http_' + r.status, message);
    }
    return data;
  }

  // ---------- formatting ----------

  function num(v, digits) {
    return typeof v === 'number' && isFinite(v) ? v.toFixed(digits) : '–';
  }

  function ageText(ms) {
    if (ms == null) return '–';
    if (ms < 10000) return (ms / 1000).toFixed(1) + ' s';
    if (ms < 120000) return Math.round(ms / 1000) + ' s';
    if (ms < 7200000) return Math.round(ms / 60000) + ' min';
    return Math.round(ms / 3600000) + ' h';
  }

  function timeText(ms) {
    const d = new Date(ms);
    const pad = (n) => String(n).padStart(2, '0');
    const hms = `${pad(d.getHours())}:${pad(d.getMinutes())}:${pad(d.getSeconds())}`;
    const now = new Date();
    if (d.toDateString() === now.toDateString()) return hms;
    return `${d.getFullYear()}-${pad(d.getMonth() + 1)}-${pad(d.getDate())} ${hms}`;
  }

  // The direction as the drive reports it; the B800 protocol has no direction readout.
  function directionText(v) {
    if (v.direction) return v.direction;
    return v.family === 'b800' ? 'direction not reported (B800 protocol)' : 'direction –';
  }

  const LOCKED_WHY = 'the gateway refuses commands to this drive (locked = true in its configuration)';
  const STANDBY_WHY = 'this gateway is a standby on the drive\'s bus: another gateway masters the line, send commands there';

  function driveState(v) {
    if (v.online === false) return 'offline';
    if (v.fault) return 'tripped';
    if (v.running === true) return 'running';
    if (v.running === false) return 'stopped';
    return 'unknown';
  }

  function notice(text, kind) {
    const n = $('#notice');
    if (!text) {
      n.hidden = true;
      return;
    }
    n.textContent = text;
    n.dataset.kind = kind || 'error';
    n.hidden = false;
  }

  // ---------- buses ----------

  function busSection(name) {
    let b = state.buses.get(name);
    if (b) return b;
    const el = $('#bus-template').content.firstElementChild.cloneNode(true);
    el.dataset.bus = name;
    field(el, 'name').textContent = name;
    field(el, 'scan-link').href = '#bus/' + encodeURIComponent(name);
    $('#buses').appendChild(el);
    const loading = $('#loading');
    if (loading) loading.remove();
    b = { view: null, el };
    state.buses.set(name, b);
    return b;
  }

  function updateBus(v) {
    const b = busSection(v.name);
    b.view = v;
    const el = b.el;
    field(el, 'port').textContent = `${v.port} · ${v.baud} ${v.serial}`;
    field(el, 'protocol').textContent = v.protocol;
    const on = field(el, 'online');
    on.textContent = v.online ? 'online' : 'offline';
    on.dataset.state = v.online ? 'online' : 'offline';
    const role = field(el, 'role');
    role.textContent = v.role || 'master';
    role.dataset.state = v.role === 'standby' ? 'standby' : 'master';
    field(el, 'transactions').textContent = String(v.transactions);
    field(el, 'timeouts').textContent = String(v.timeouts);
    field(el, 'checksum_errors').textContent = String(v.checksum_errors);
    field(el, 'retries').textContent = String(v.retries);
    field(el, 'utilization').textContent = num(v.utilization * 100, 1) + ' %';
    for (const id of v.drives || []) {
      const d = state.drives.get(id);
      if (d && d.tile && d.tile.parentElement !== $('.tiles', el)) $('.tiles', el).appendChild(d.tile);
    }
    addOption('#dense-bus', v.name);
  }

  // ---------- drives ----------

  function createTile(v) {
    const tile = $('#tile-template').content.firstElementChild.cloneNode(true);
    tile.dataset.drive = v.id;
    field(tile, 'id').textContent = v.id;
    field(tile, 'params-link').href = '#drive/' + encodeURIComponent(v.id);
    for (const btn of tile.querySelectorAll('[data-action]')) {
      btn.addEventListener('click', () => onAction(v.id, btn.dataset.action));
    }
    field(tile, 'speed').addEventListener('keydown', (ev) => {
      if (ev.key === 'Enter') onAction(v.id, 'speed');
    });
    const track = $('.gauge-track', tile);
    track.setAttribute('d', arcPath(1));
    return tile;
  }

  // A drive's new values: kept at once, shown with the next flush (at most every 50 ms), so that
  // a plant's worth of updates costs one pass over the page, not one per message.
  function updateDrive(v, receivedAt) {
    let d = state.drives.get(v.id);
    if (!d) {
      d = { view: v, receivedAt: 0, tile: null, row: null, samples: [], trendOpen: false, history: [] };
      state.drives.set(v.id, d);
      addOption('#event-drive', v.id);
      addOption('#dense-bus', v.bus);
      state.denseStale = true;
    }
    if (d.view && driveState(d.view) !== driveState(v)) state.denseStale = true;
    d.view = v;
    d.receivedAt = receivedAt || performance.now();
    if (typeof v.output_hz === 'number' || typeof v.current_a === 'number') {
      const ts = v.last_seen_ms || Date.now();
      const last = d.samples[d.samples.length - 1];
      if (!last || last.t < ts) d.samples.push({ t: ts, hz: v.output_hz, a: v.current_a });
      const cut = Date.now() - TREND_SPAN_MS;
      while (d.samples.length && d.samples[0].t < cut) d.samples.shift();
    }
    state.dirty.add(v.id);
    if (!state.flushTimer) state.flushTimer = setTimeout(flush, 50);
  }

  function flush() {
    state.flushTimer = null;
    if (!state.view) chooseView();
    const ids = [...state.dirty];
    state.dirty.clear();
    if (state.view === 'cards') {
      for (const id of ids) renderTile(state.drives.get(id));
    } else {
      for (const id of ids) renderRow(state.drives.get(id));
      if (state.denseStale) renderDense();
    }
  }

  function renderTile(d) {
    const v = d.view;
    if (!d.tile) {
      d.tile = createTile(v);
      $('.tiles', busSection(v.bus).el).appendChild(d.tile);
    }
    const t = d.tile;
    const st = driveState(v);
    const stEl = field(t, 'state');
    stEl.textContent = st;
    stEl.dataset.state = st;
    t.dataset.state = st;
    field(t, 'family').textContent = `${v.family} · ${v.protocol} #${v.address}`;
    const lock = field(t, 'locked');
    lock.hidden = !v.locked;
    lock.title = v.locked ? 'locked: ' + LOCKED_WHY : '';
    field(t, 'source').hidden = v.source !== 'standby';
    applyLock(d);
    const hz = field(t, 'output_hz');
    hz.textContent = num(v.output_hz, 2);
    hz.dataset.value = v.output_hz == null ? '' : String(v.output_hz);
    field(t, 'setpoint_hz').textContent = num(v.setpoint_hz, 2);
    field(t, 'current_a').textContent = num(v.current_a, 2);
    field(t, 'direction').textContent = directionText(v);
    renderValues(field(t, 'values'), v.values);
    const f = field(t, 'fault');
    if (v.fault) {
      f.textContent = `fault ${v.fault.code}: ${v.fault.text}`;
      f.hidden = false;
    } else {
      f.hidden = true;
      f.textContent = '';
    }
    const link = field(t, 'link');
    const online = v.online === true ? 'online' : v.online === false ? 'offline' : 'not polled yet';
    link.textContent = `${online} · errors ${num(v.error_rate * 100, 1)} % of ${v.polls} polls`;
    link.title = v.last_error || '';
    updateGauge(t, v);
    updateAge(d);
    if (d.trendOpen) drawTrend(d);
  }

  // A templated drive's named values (its template's [values]), a name and a value with its
  // unit each; the list is rebuilt only when its text changes.
  function renderValues(el, values) {
    const entries = Object.entries(values || {});
    el.hidden = entries.length === 0;
    const shown = entries.map(([name, x]) => [name, x.unit ? `${x.value} ${x.unit}` : String(x.value)]);
    const key = JSON.stringify(shown);
    if (el.dataset.shown === key) return;
    el.dataset.shown = key;
    el.replaceChildren(...shown.flatMap(([name, text]) => {
      const dt = document.createElement('dt');
      dt.textContent = name;
      const dd = document.createElement('dd');
      dd.dataset.value = name;
      dd.textContent = text;
      return [dt, dd];
    }));
  }

  // A locked drive's command controls are disabled, and say why, as are those of a drive this
  // gateway only hears as a standby; Trend stays.
  function applyLock(d) {
    const why = d.view.locked ? 'locked: ' + LOCKED_WHY
      : d.view.source === 'standby' ? 'standby: ' + STANDBY_WHY : '';
    for (const el of d.tile.querySelectorAll('.controls button:not([data-action="trend"]), .controls input')) {
      el.disabled = why !== '' || d.sending === true;
      el.title = why;
    }
    const line = field(d.tile, 'locked-why');
    line.hidden = why === '';
    line.textContent = why === '' ? '' : 'Commands are off: ' + why.replace(/^[a-z]+: /, '') + '.';
  }

  // The values' age now: as the gateway gave it, plus the time since it arrived.
  function ageNow(d) {
    return d.view.age_ms == null ? null : d.view.age_ms + (performance.now() - d.receivedAt);
  }

  function updateAge(d) {
    const age = ageNow(d);
    const stale = age != null && age > Math.max(3 * d.view.poll_ms, 3000);
    if (state.view === 'cards' && d.tile) {
      field(d.tile, 'age').textContent = ageText(age);
      d.tile.classList.toggle('stale', stale);
    } else if (state.view === 'table' && d.row) {
      const cell = d.row.cells[7];
      const text = ageText(age);
      if (cell.textContent !== text) cell.textContent = text;
      d.row.classList.toggle('stale', stale);
    }
  }

  // ---------- gauge ----------

  const CX = 60;
  const CY = 64;
  const R = 46;

  function arcPoint(frac, r) {
    const a = Math.PI * (1 - frac);
    return [CX + r * Math.cos(a), CY - r * Math.sin(a)];
  }

  function arcPath(frac) {
    const f = Math.max(0, Math.min(1, frac));
    const [x0, y0] = arcPoint(0, R);
    const [x1, y1] = arcPoint(f, R);
    return `M ${x0.toFixed(2)} ${y0.toFixed(2)} A ${R} ${R} 0 0 1 ${x1.toFixed(2)} ${y1.toFixed(2)}`;
  }

  function scaleMax(v) {
    const m = Math.max(60, Math.abs(v.output_hz || 0), Math.abs(v.setpoint_hz || 0));
    return Math.ceil(m / 10) * 10;
  }

  function updateGauge(t, v) {
    const max = scaleMax(v);
    const out = Math.abs(v.output_hz || 0);
    const value = $('.gauge-value', t);
    value.setAttribute('d', out > 0 ? arcPath(out / max) : '');
    $('.gauge-max', t).textContent = String(max);
    const sp = $('.gauge-setpoint', t);
    if (typeof v.setpoint_hz === 'number') {
      const f = Math.abs(v.setpoint_hz) / max;
      const [x1, y1] = arcPoint(f, R - 9);
      const [x2, y2] = arcPoint(f, R + 9);
      sp.setAttribute('x1', x1.toFixed(2));
      sp.setAttribute('y1', y1.toFixed(2));
      sp.setAttribute('x2', x2.toFixed(2));
      sp.setAttribute('y2', y2.toFixed(2));
      sp.classList.remove('none');
    } else {
      sp.classList.add('none');
    }
  }

  // ---------- trend ----------

  async function toggleTrend(id) {
    const d = state.drives.get(id);
    if (!d) return;
    d.trendOpen = !d.trendOpen;
    const box = field(d.tile, 'trend');
    box.hidden = !d.trendOpen;
    $('[data-action="trend"]', d.tile).setAttribute('aria-expanded', String(d.trendOpen));
    if (!d.trendOpen) return;
    drawTrend(d);
    const since = Date.now() - TREND_SPAN_MS;
    try {
      const points = await api('GET', `/api/drives/${encodeURIComponent(id)}/trend?since=${since}&resolution=1s`);
      d.history = (points || []).map((p) => ({ t: p.time_ms, hz: p.output_hz, a: p.current_a }));
      d.historyNote = '';
    } catch (e) {
      d.history = [];
      d.historyNote = 'no history: ' + e.message;
    }
    drawTrend(d);
  }

  function drawTrend(d) {
    const now = Date.now();
    const firstLive = d.samples.length ? d.samples[0].t : Infinity;
    const cut = now - TREND_SPAN_MS;
    const pts = d.history.filter((p) => p.t >= cut && p.t < firstLive).concat(d.samples.filter((p) => p.t >= cut));
    // The window is the last 10 minutes, or less while there is less to show (at least a minute).
    const span = Math.max(60000, Math.min(TREND_SPAN_MS, pts.length ? now - pts[0].t : 0));
    const from = now - span;
    let hzMax = 10;
    let aMax = 1;
    for (const p of pts) {
      if (typeof p.hz === 'number') hzMax = Math.max(hzMax, Math.abs(p.hz));
      if (typeof p.a === 'number') aMax = Math.max(aMax, Math.abs(p.a));
    }
    hzMax *= 1.1;
    aMax *= 1.1;
    const W = 320;
    const H = 120;
    const line = (key, max) => pts
      .filter((p) => typeof p[key] === 'number')
      .map((p) => `${(((p.t - from) / span) * W).toFixed(1)},${(H - (Math.abs(p[key]) / max) * (H - 4) - 2).toFixed(1)}`)
      .join(' ');
    const t = d.tile;
    $('.trend-hz', t).setAttribute('points', line('hz', hzMax));
    $('.trend-a', t).setAttribute('points', line('a', aMax));
    field(t, 'trend-hz-max').textContent = `≤ ${num(hzMax, 0)}`;
    field(t, 'trend-a-max').textContent = `≤ ${num(aMax, 1)}`;
    const spanText = span >= TREND_SPAN_MS ? 'last 10 min' : `last ${Math.round(span / 1000)} s`;
    field(t, 'trend-span').textContent = d.historyNote ? `· ${spanText} · ${d.historyNote}` : `· ${spanText}`;
    // The time axis: the clock time at the left edge, a quarter, the middle, three quarters, now.
    const ticks = $('.trend-axis', t).children;
    for (let i = 0; i < ticks.length; i++) ticks[i].textContent = timeText(from + (span * i) / (ticks.length - 1));
  }

  // ---------- commands ----------

  function tileMessage(id, text, kind) {
    const d = state.drives.get(id);
    if (!d || !d.tile) return;
    const m = field(d.tile, 'message');
    m.textContent = text;
    m.dataset.kind = kind;
    m.hidden = !text;
  }

  function onAction(id, action) {
    if (action === 'trend') {
      toggleTrend(id);
      return;
    }
    sendCommand(id, action);
  }

  async function sendCommand(id, action) {
    const d = state.drives.get(id);
    if (!d) return;
    let body;
    let label = action;
    if (action === 'speed') {
      const raw = field(d.tile, 'speed').value.trim();
      const hz = Number(raw);
      if (raw === '' || !isFinite(hz)) {
        tileMessage(id, 'Enter a speed in Hz first, e.g. 40.', 'error');
        return;
      }
      body = { hz };
      label = `speed ${hz} Hz`;
    }
    if (!token()) {
      askToken(`A write token is needed to send "${label}" to ${id}.`, () => sendCommand(id, action));
      return;
    }
    d.sending = true;
    applyLock(d);
    tileMessage(id, `${label}: sent, waiting for the drive…`, 'pending');
    try {
      const res = await api('POST', `/api/drives/${encodeURIComponent(id)}/${action}`, body);
      if (res && res.drive) updateDrive(res.drive);
      // The answer comes when the drive confirmed; its new values follow with the next poll.
      tileMessage(id, `${label}: ok, the drive confirmed`, 'ok');
    } catch (e) {
      if (e.status === 401) {
        setToken('');
        tileMessage(id, `${label}: the token was not accepted (401 ${e.message}). Enter a valid token.`, 'error');
        askToken('The token was not accepted: enter a valid write token.', () => sendCommand(id, action));
      } else if (e.status === 403) {
        tileMessage(id, `${label}: this token may only read (403 ${e.message}). A write token is needed.`, 'error');
        askToken('This token may only read: enter a write token to send commands.', () => sendCommand(id, action));
      } else {
        tileMessage(id, `${label}: ${e.message}`, 'error');
      }
    } finally {
      d.sending = false;
      applyLock(d);
    }
  }

  // ---------- the table of all drives ----------

  // Adds `value` to the <select> `selector` unless it is there already.
  function addOption(selector, value) {
    const sel = $(selector);
    for (const o of sel.options) if (o.value === value) return;
    const o = document.createElement('option');
    o.value = value;
    o.textContent = value;
    sel.appendChild(o);
  }

  function createRow(d) {
    const tr = document.createElement('tr');
    tr.dataset.row = d.view.id;
    for (let i = 0; i < 8; i++) tr.appendChild(document.createElement('td'));
    const show = document.createElement('button');
    show.type = 'button';
    show.className = 'link-button';
    show.textContent = d.view.id;
    show.title = 'show its card';
    show.addEventListener('click', () => showCard(d.view.id));
    tr.cells[0].appendChild(show);
    for (const i of [3, 4, 5, 7]) tr.cells[i].className = 'num';
    const badge = document.createElement('span');
    badge.className = 'state';
    tr.cells[2].appendChild(badge);
    return tr;
  }

  function setCell(cell, text) {
    if (cell.textContent !== text) cell.textContent = text;
  }

  function renderRow(d) {
    if (!d.row) d.row = createRow(d);
    const v = d.view;
    const c = d.row.cells;
    setCell(c[1], v.bus);
    const st = driveState(v);
    const badge = c[2].firstChild;
    setCell(badge, st);
    badge.dataset.state = st;
    setCell(c[3], num(v.output_hz, 2));
    setCell(c[4], num(v.setpoint_hz, 2));
    setCell(c[5], num(v.current_a, 2));
    setCell(c[6], v.fault ? `${v.fault.code}: ${v.fault.text}` : '');
    d.row.classList.toggle('locked', !!v.locked);
    updateAge(d);
  }

  const collator = new Intl.Collator(undefined, { numeric: true });

  function sortValue(d, key) {
    const v = d.view;
    switch (key) {
      case 'state': return driveState(v);
      case 'fault': return v.fault ? v.fault.text : null;
      case 'age': return ageNow(d);
      default: return v[key];
    }
  }

  // By `key` in `dir`, unknown values last whatever the direction, then by name.
  function compareBy(a, b, key, dir) {
    const x = sortValue(a, key);
    const y = sortValue(b, key);
    const byName = collator.compare(a.view.id, b.view.id);
    if (x == null || y == null) return x == null && y == null ? byName : x == null ? 1 : -1;
    const c = typeof x === 'number' && typeof y === 'number' ? x - y : collator.compare(String(x), String(y));
    return dir * c || byName;
  }

  // Filters, sorts and lays out the rows: on a filter, a sort, a new drive or a change of state.
  function renderDense() {
    state.denseStale = false;
    const bus = $('#dense-bus').value;
    const want = $('#dense-state').value;
    const search = $('#dense-search').value.trim().toLowerCase();
    const { key, dir } = state.sort;
    const shown = [];
    for (const d of state.drives.values()) {
      const v = d.view;
      if (bus && v.bus !== bus) continue;
      if (want && driveState(v) !== want) continue;
      if (search && !v.id.toLowerCase().includes(search)) continue;
      if (!d.row) renderRow(d);
      shown.push(d);
    }
    shown.sort((a, b) => compareBy(a, b, key, dir));
    $('#dense-rows').replaceChildren(...shown.map((d) => d.row));
    $('#dense-count').textContent = `${shown.length} of ${state.drives.size} drives`;
    for (const th of document.querySelectorAll('#dense-table th[data-sort]')) {
      th.setAttribute('aria-sort', th.dataset.sort === key ? (dir > 0 ? 'ascending' : 'descending') : 'none');
    }
  }

  function wireDense() {
    for (const th of document.querySelectorAll('#dense-table th[data-sort]')) {
      th.addEventListener('click', () => {
        const key = th.dataset.sort;
        state.sort = { key, dir: state.sort.key === key ? -state.sort.dir : 1 };
        renderDense();
      });
    }
    $('#dense-bus').addEventListener('change', renderDense);
    $('#dense-state').addEventListener('change', renderDense);
    $('#dense-search').addEventListener('input', renderDense);
  }

  // ---------- cards or table ----------

  function chooseView() {
    let saved = null;
    try {
      saved = sessionStorage.getItem(VIEW_KEY);
    } catch (_) {
      saved = null;
    }
    setView(saved === 'cards' || saved === 'table' ? saved : state.drives.size > TABLE_FROM ? 'table' : 'cards', false);
  }

  function setView(view, remember) {
    state.view = view;
    if (remember) {
      try {
        sessionStorage.setItem(VIEW_KEY, view);
      } catch (_) {
        // Not kept: the choice lasts until the page reloads.
      }
    }
    $('#buses').hidden = view !== 'cards';
    $('#dense').hidden = view !== 'table';
    for (const b of document.querySelectorAll('[data-view]')) b.setAttribute('aria-pressed', String(b.dataset.view === view));
    state.dirty.clear();
    if (view === 'cards') {
      for (const d of state.drives.values()) renderTile(d);
      for (const b of state.buses.values()) if (b.view) updateBus(b.view);
    } else {
      for (const d of state.drives.values()) renderRow(d);
      renderDense();
    }
  }

  function showCard(id) {
    setView('cards', true);
    const d = state.drives.get(id);
    if (d && d.tile) d.tile.scrollIntoView({ block: 'center' });
  }

  // ---------- events ----------

  function eventMatches(e) {
    const drive = $('#event-drive').value;
    const kind = $('#event-kind').value;
    return (!drive || e.drive === drive) && (!kind || e.kind === kind);
  }

  // A trip's snapshot of the drive just before it: "before: running 30.00 Hz (set 30.00 Hz), 7.5 A".
  function tripBefore(b) {
    if (!b) return '';
    const hz = (v) => (v == null ? '-' : `${Number(v).toFixed(2)} Hz`);
    const parts = [`${b.running ? 'running' : 'stopped'} ${hz(b.output_hz)}`];
    if (b.setpoint_hz != null) parts[0] += ` (set ${hz(b.setpoint_hz)})`;
    if (b.current_a != null) parts.push(`${Number(b.current_a).toFixed(1)} A`);
    return ` — before: ${parts.join(', ')}`;
  }

  function eventWhat(e) {
    if (e.action) return e.action;
    const det = e.detail || {};
    if (e.kind === 'trip' && det.text) return `${det.code != null ? det.code + ': ' : ''}${det.text}${tripBefore(det.before)}`;
    if (det.text) return `${det.code != null ? det.code + ': ' : ''}${det.text}`;
    if (det.error) return det.error;
    if (e.kind === 'started' && det.drives != null) return `${det.buses} buses, ${det.drives} drives`;
    return '';
  }

  function eventRow(e) {
    const tr = document.createElement('tr');
    tr.dataset.kind = e.kind;
    if (e.result && e.result !== 'ok') tr.classList.add('failed');
    const cells = [timeText(e.time_ms), e.kind.replace(/_/g, ' '), e.drive || e.bus || '', e.actor || '', eventWhat(e), e.result || ''];
    for (const c of cells) {
      const td = document.createElement('td');
      td.textContent = c;
      tr.appendChild(td);
    }
    return tr;
  }

  function renderEvents() {
    const body = $('#event-rows');
    body.replaceChildren(...state.events.filter(eventMatches).map(eventRow));
  }

  function addEvent(e, live) {
    // The store's id where there is one; the content as well, so that events never collapse.
    const key = `${e.id || 0}|${e.time_ms}|${e.kind}|${e.bus}|${e.drive}|${e.action}|${e.result}`;
    if (state.eventIds.has(key)) return;
    state.eventIds.add(key);
    state.events.push(e);
    state.events.sort((a, b) => b.time_ms - a.time_ms || (b.id || 0) - (a.id || 0));
    if (state.events.length > MAX_EVENTS) state.events.length = MAX_EVENTS;
    if (live && eventMatches(e)) renderEvents();
  }

  async function loadEvents() {
    const params = new URLSearchParams({ limit: '200' });
    const drive = $('#event-drive').value;
    const kind = $('#event-kind').value;
    if (drive) params.set('drive', drive);
    if (kind) params.set('kind', kind);
    const status = $('#event-status');
    try {
      const list = await api('GET', '/api/events?' + params);
      for (const e of list || []) addEvent(e, false);
      status.textContent = '';
    } catch (e) {
      status.textContent = 'stored events not available: ' + e.message + ' (live events still show)';
    }
    renderEvents();
  }

  // ---------- loading and the live stream ----------

  async function loadDrivesAndBuses() {
    const drives = await api('GET', '/api/drives');
    let buses = null;
    try {
      buses = await api('GET', '/api/buses');
    } catch (e) {
      if (e.status === 401) throw e;
    }
    const now = performance.now();
    if (buses) for (const b of buses) busSection(b.name);
    for (const v of drives) updateDrive(v, now);
    if (buses) for (const b of buses) updateBus(b);
    else for (const v of drives) busSection(v.bus);
  }

  function handleChange(type, data) {
    switch (type || data.type) {
      case 'drive':
        updateDrive(data);
        break;
      case 'bus':
        updateBus(data);
        break;
      case 'event':
        addEvent(data, true);
        break;
      case 'lagged':
        // The stream skipped messages this page was too slow for: read the current state.
        loadDrivesAndBuses().catch(() => {});
        loadEvents();
        break;
      default:
        break;
    }
  }

  function setLive(s, text) {
    const el = $('#live');
    el.dataset.state = s;
    el.textContent = text;
  }

  function startPolling() {
    if (state.pollTimer) return;
    state.pollTimer = setInterval(() => {
      loadDrivesAndBuses().then(() => notice(''), (e) => notice('Cannot read the drives: ' + e.message));
    }, 2000);
  }

  function stopPolling() {
    if (state.pollTimer) clearInterval(state.pollTimer);
    state.pollTimer = null;
  }

  async function stream() {
    let delay = 1000;
    for (;;) {
      try {
        const headers = { Accept: 'text/event-stream' };
        if (token()) headers.Authorization = 'Bearer ' + token();
        const r = await fetch('/api/stream', { headers, cache: 'no-store' });
        if (!r.ok || !r.body) throw new Error(`the live stream answered ${r.status}`);
        state.streaming = true;
        stopPolling();
        setLive('live', 'live');
        delay = 1000;
        // Catch up on what happened while the stream was down.
        loadDrivesAndBuses().catch(() => {});
        const reader = r.body.getReader();
        const dec = new TextDecoder();
        let buf = '';
        for (;;) {
          const { value, done } = await reader.read();
          if (done) break;
          buf += dec.decode(value, { stream: true });
          let cut;
          while ((cut = buf.search(/\r?\n\r?\n/)) >= 0) {
            const block = buf.slice(0, cut);
            buf = buf.slice(cut).replace(/^\r?\n\r?\n/, '');
            let type = '';
            const data = [];
            for (const line of block.split(/\r?\n/)) {
              if (line.startsWith('event:')) type = line.slice(6).trim();
              else if (line.startsWith('data:')) data.push(line.slice(5).replace(/^ /, ''));
            }
            if (!data.length) continue;
            try {
              handleChange(type, JSON.parse(data.join('\n')));
            } catch (_) {
              // A message that is not JSON is not ours: skip it.
            }
          }
        }
        throw new Error('the live stream ended');
      } catch (e) {
        state.streaming = false;
        setLive('down', 'polling (' + e.message + ')');
        startPolling();
      }
      await new Promise((res) => setTimeout(res, delay));
      delay = Math.min(delay * 2, 15000);
    }
  }

  async function start() {
    try {
      await loadDrivesAndBuses();
      notice('');
    } catch (e) {
      if (e.status === 401 || e.status === 403) {
        askToken('This gateway needs a token to read: enter a read or write token.', start);
        notice('Reading needs a token (' + e.message + ').');
      } else {
        notice('Cannot read the drives: ' + e.message + ' — retrying.');
        setTimeout(start, 3000);
      }
      return;
    }
    loadEvents();
    stream();
  }

  function init() {
    updateTokenButton();
    wireTokenDialog();
    wireDense();
    for (const b of document.querySelectorAll('[data-view]')) b.addEventListener('click', () => setView(b.dataset.view, true));
    // The list is filtered here (renderEvents); the store is asked for more of the new filter.
    // Nothing is cleared: without a store the live events are all there is.
    $('#event-drive').addEventListener('change', () => { renderEvents(); loadEvents(); });
    $('#event-kind').addEventListener('change', () => { renderEvents(); loadEvents(); });
    setInterval(() => {
      for (const d of state.drives.values()) updateAge(d);
      // Sorted by a value that changes by itself (age, output, current): keep the order true.
      if (state.view === 'table' && !['id', 'bus'].includes(state.sort.key)) renderDense();
    }, 1000);
    start();
  }

  // The commissioning pages (workbench.js) use the same token and API client.
  window.drivebus = { api, token, askToken, notice };

  if (document.readyState === 'loading') document.addEventListener('DOMContentLoaded', init);
  else init();
})();
