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

  const state = {
    drives: new Map(), // id -> { view, receivedAt, tile, samples: [{t, hz, a}], trendOpen, history }
    buses: new Map(), // name -> { view, el }
    events: [],
    eventIds: new Set(),
    streaming: false,
    pollTimer: null,
    pendingAfterToken: null,
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
    field(el, 'transactions').textContent = String(v.transactions);
    field(el, 'timeouts').textContent = String(v.timeouts);
    field(el, 'checksum_errors').textContent = String(v.checksum_errors);
    field(el, 'retries').textContent = String(v.retries);
    field(el, 'utilization').textContent = num(v.utilization * 100, 1) + ' %';
    for (const id of v.drives || []) {
      const d = state.drives.get(id);
      if (d && d.tile.parentElement !== $('.tiles', el)) $('.tiles', el).appendChild(d.tile);
    }
  }

  // ---------- drives ----------

  function createTile(v) {
    const tile = $('#tile-template').content.firstElementChild.cloneNode(true);
    tile.dataset.drive = v.id;
    field(tile, 'id').textContent = v.id;
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

  function updateDrive(v, receivedAt) {
    let d = state.drives.get(v.id);
    if (!d) {
      d = { view: v, receivedAt: 0, tile: createTile(v), samples: [], trendOpen: false, history: [] };
      state.drives.set(v.id, d);
      $('.tiles', busSection(v.bus).el).appendChild(d.tile);
      addDriveOption(v.id);
    }
    d.view = v;
    d.receivedAt = receivedAt || performance.now();
    const t = d.tile;
    const st = driveState(v);
    const stEl = field(t, 'state');
    stEl.textContent = st;
    stEl.dataset.state = st;
    t.dataset.state = st;
    field(t, 'family').textContent = `${v.family} · ${v.protocol} #${v.address}`;
    field(t, 'locked').hidden = !v.locked;
    const hz = field(t, 'output_hz');
    hz.textContent = num(v.output_hz, 2);
    hz.dataset.value = v.output_hz == null ? '' : String(v.output_hz);
    field(t, 'setpoint_hz').textContent = num(v.setpoint_hz, 2);
    field(t, 'current_a').textContent = num(v.current_a, 2);
    field(t, 'direction').textContent = v.direction ? v.direction : '';
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
    if (typeof v.output_hz === 'number' || typeof v.current_a === 'number') {
      const ts = v.last_seen_ms || Date.now();
      const last = d.samples[d.samples.length - 1];
      if (!last || last.t < ts) d.samples.push({ t: ts, hz: v.output_hz, a: v.current_a });
      const cut = Date.now() - TREND_SPAN_MS;
      while (d.samples.length && d.samples[0].t < cut) d.samples.shift();
    }
    if (d.trendOpen) drawTrend(d);
  }

  function updateAge(d) {
    const v = d.view;
    const el = field(d.tile, 'age');
    if (v.age_ms == null) {
      el.textContent = '–';
      return;
    }
    const age = v.age_ms + (performance.now() - d.receivedAt);
    el.textContent = ageText(age);
    d.tile.classList.toggle('stale', age > Math.max(3 * v.poll_ms, 3000));
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
  }

  // ---------- commands ----------

  function tileMessage(id, text, kind) {
    const d = state.drives.get(id);
    if (!d) return;
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
    const buttons = d.tile.querySelectorAll('.controls button:not([data-action="trend"])');
    buttons.forEach((b) => { b.disabled = true; });
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
      buttons.forEach((b) => { b.disabled = false; });
    }
  }

  // ---------- events ----------

  function addDriveOption(id) {
    const sel = $('#event-drive');
    for (const o of sel.options) if (o.value === id) return;
    const o = document.createElement('option');
    o.value = id;
    o.textContent = id;
    sel.appendChild(o);
  }

  function eventMatches(e) {
    const drive = $('#event-drive').value;
    const kind = $('#event-kind').value;
    return (!drive || e.drive === drive) && (!kind || e.kind === kind);
  }

  function eventWhat(e) {
    if (e.action) return e.action;
    const det = e.detail || {};
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
    // The list is filtered here (renderEvents); the store is asked for more of the new filter.
    // Nothing is cleared: without a store the live events are all there is.
    $('#event-drive').addEventListener('change', () => { renderEvents(); loadEvents(); });
    $('#event-kind').addEventListener('change', () => { renderEvents(); loadEvents(); });
    setInterval(() => { for (const d of state.drives.values()) updateAge(d); }, 500);
    start();
  }

  if (document.readyState === 'loading') document.addEventListener('DOMContentLoaded', init);
  else init();
})();
