"""`tinbuild info --json` as an HTML page for Processing's results viewer.

The page is one self-contained file (inline style, no scripts, no images), since the results viewer and
the browser a user may open it in show it from disk.  It reads only the stable keys that `info --json`
documents (points, bounds, crs.*, classes, returns, width) plus the per-file and coherence facts when
present, and leaves out what is missing, so an older or newer tinbuild's JSON still renders.  Every
value from the report is escaped.
"""
import html
import math

CLASS_NAMES = {
    0: 'Created, never classified', 1: 'Unclassified', 2: 'Ground', 3: 'Low vegetation', 4: 'Medium vegetation',
    5: 'High vegetation', 6: 'Building', 7: 'Low point (noise)', 8: 'Model key-point', 9: 'Water', 10: 'Rail',
    11: 'Road surface', 12: 'Overlap', 13: 'Wire guard', 14: 'Wire conductor', 15: 'Transmission tower',
    16: 'Wire-structure connector', 17: 'Bridge deck', 18: 'High noise',
}

STYLE = """
body { font-family: sans-serif; font-size: 10pt; margin: 1em; }
h1 { font-size: 14pt; } h2 { font-size: 11pt; margin-top: 1.2em; border-bottom: 1px solid #999; }
table { border-collapse: collapse; } td, th { padding: 2px 8px; text-align: left; vertical-align: top; }
th { background: #e8e8e8; } td.n { text-align: right; font-family: monospace; }
tr:nth-child(even) td { background: #f6f6f6; } .warn { color: #a04000; }
"""


def _e(value):
    return html.escape('' if value is None else str(value))


def _n(value, digits=None):
    if value is None:
        return ''
    if isinstance(value, int):
        return f'{value:,}'
    if isinstance(value, float):
        if digits is not None:
            return f'{value:,.{digits}f}'
        return f'{value:,.6g}' if abs(value) < 1e6 else f'{value:,.3f}'
    return str(value)


def _table(rows, header=None, numeric=()):
    out = ['<table>']
    if header:
        out.append('<tr>' + ''.join(f'<th>{_e(h)}</th>' for h in header) + '</tr>')
    for row in rows:
        cells = []
        for i, cell in enumerate(row):
            cls = ' class="n"' if i in numeric else ''
            cells.append(f'<td{cls}>{cell}</td>')
        out.append('<tr>' + ''.join(cells) + '</tr>')
    out.append('</table>')
    return '\n'.join(out)


def _bounds(b):
    if not b or 'min' not in b or 'max' not in b:
        return ''
    lo, hi = b['min'], b['max']
    axes = 'xyz'
    return '<br>'.join(f'{axes[i]} {_e(_n(float(lo[i]), 3))} .. {_e(_n(float(hi[i]), 3))}'
                       for i in range(min(len(lo), len(hi), 3)))


def _crs(crs):
    if not crs or not crs.get('name'):
        return [('CRS', '<span class="warn">none: the files declare no CRS (assign one with the CRS '
                        'parameter)</span>')]
    rows = [('CRS', _e(crs.get('name')) + (f" (EPSG:{_e(crs['epsg'])})" if crs.get('epsg') else ''))]
    if crs.get('vertical_name') or crs.get('vertical_epsg'):
        rows.append(('vertical CRS', _e(crs.get('vertical_name')) +
                     (f" (EPSG:{_e(crs['vertical_epsg'])})" if crs.get('vertical_epsg') else '')))
    if crs.get('units'):
        rows.append(('units', _e(crs['units']) + (f", heights {_e(crs['vertical_units'])}"
                                                   if crs.get('vertical_units') else '')))
    if crs.get('source'):
        rows.append(('CRS from', _e(crs['source'])))
    for note in crs.get('notes') or []:
        rows.append(('note', _e(note)))
    return rows


def infoHtml(data, version=''):
    """The page for one `info --json` report."""
    points = data.get('points')
    crs = data.get('crs') or {}
    parts = ['<!DOCTYPE html>', '<html><head><meta charset="utf-8"><title>tinbuild info</title>',
             f'<style>{STYLE}</style></head><body>']
    files = data.get('files') or []
    title = ', '.join(f.get('path', '').rsplit('/', 1)[-1] for f in files[:3]) + (' ...' if len(files) > 3 else '')
    parts.append(f'<h1>Survey summary: {_e(title)}</h1>')

    survey = [('points', _e(_n(points)))]
    survey.append(('bounds', _bounds(data.get('bounds'))))
    survey += _crs(crs)
    if data.get('area_km2') is not None:
        survey.append(('area', _e(_n(float(data['area_km2']), 4)) + ' km&sup2; (bounding box)'))
    density = data.get('density_per_m2')
    if density:
        survey.append(('density', f'{_e(_n(float(density), 4))} points/m&sup2;, spacing '
                                  f'{_e(_n(1.0 / math.sqrt(float(density)), 3))} m'))
    for key, label in (('withheld', 'withheld'), ('duplicates_xy', 'xy duplicates'), ('synthetic', 'synthetic'),
                       ('key_point', 'key-point'), ('overlap', 'overlap')):
        if data.get(key):
            share = f' ({100.0 * data[key] / points:.2f}%)' if points else ''
            survey.append((label, _e(_n(data[key])) + share))
    parts.append('<h2>Survey</h2>')
    parts.append(_table(survey))

    classes = data.get('classes') or {}
    if classes:
        rows = []
        for code, count in sorted(classes.items(), key=lambda kv: int(kv[0])):
            share = f'{100.0 * count / points:.1f}%' if points else ''
            rows.append((_e(code), _e(CLASS_NAMES.get(int(code), 'user-defined')), _e(_n(count)), _e(share)))
        parts.append('<h2>Points by class</h2>')
        parts.append(_table(rows, ['class', 'name', 'points', 'share'], numeric=(0, 2, 3)))

    returns = data.get('returns') or {}
    if returns:
        parts.append('<h2>Points by return number</h2>')
        parts.append(_table([(_e(k), _e(_n(v))) for k, v in sorted(returns.items(), key=lambda kv: int(kv[0]))],
                            ['return', 'points'], numeric=(0, 1)))

    coherence = data.get('coherence') or {}
    if coherence or data.get('width') is not None:
        rows = []
        if coherence:
            rows.append(('grid', f"depth {_e(coherence.get('depth'))}: {_e(_n(coherence.get('grid_cells')))} cells "
                                 f"of {_e(_n(coherence.get('cell_size'), 2))}, {_e(_n(coherence.get('occupied_cells')))} "
                                 'occupied'))
            rows.append(('points per cell', f"{_e(_n(coherence.get('average_per_cell'), 1))} on average, "
                                            f"{_e(_n(coherence.get('max_per_cell')))} at most"))
        width = data.get('width')
        if width is not None:
            frac = coherence.get('width_fraction')
            rows.append(('stream width', f'{_e(_n(width))} points' +
                         (f' ({100.0 * frac:.1f}% of the survey buffered at most)' if frac is not None else '')))
        parts.append('<h2>Stream coherence</h2>')
        parts.append(_table(rows))

    if files:
        rows = []
        for f in files:
            comp = f.get('compression') or {}
            fmt = f"{_e(f.get('format'))} {_e(f.get('version'))}"
            if comp.get('ratio'):
                fmt += f" ({_e(comp.get('compressor'))}, {float(comp['ratio']):.2f}:1)"
            fcrs = f.get('crs') or {}
            crsText = _e(fcrs.get('name') or 'none') + (f" (EPSG:{_e(fcrs['epsg'])})" if fcrs.get('epsg') else '')
            rows.append((_e(f.get('path')), fmt, _e(f.get('point_format')), _e(_n(f.get('points'))), crsText,
                         _e(f.get('generating_software') or '')))
        parts.append('<h2>Files</h2>')
        parts.append(_table(rows, ['file', 'format', 'point format', 'points', 'CRS', 'software'], numeric=(2, 3)))

    warnings = list(data.get('warnings') or [])
    for f in files:
        warnings += [w for w in (f.get('warnings') or []) if w not in warnings]
    if warnings:
        parts.append('<h2>Warnings</h2><ul>')
        for w in warnings:
            text = w.get('message') if isinstance(w, dict) else w
            where = w.get('file') if isinstance(w, dict) else ''
            parts.append(f'<li class="warn">{_e(where + ": " if where else "")}{_e(text)}</li>')
        parts.append('</ul>')

    parts.append(f'<p style="color:#777">tinbuild {_e(version)} info</p></body></html>')
    return '\n'.join(parts)
