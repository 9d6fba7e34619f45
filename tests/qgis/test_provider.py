#!/usr/bin/python3
"""The QGIS Processing provider (share/qgis/tinbuild_processing), headless, the way QGIS runs it.

    QT_QPA_PLATFORM=offscreen /usr/bin/python3 tests/qgis/test_provider.py --tinbuild build/tinbuild \
        --data ../shared/data --workdir /tmp/tinbuild-provider

QGIS's own plugin machinery (qgis.utils: metadata.txt, classFactory without iface, initProcessing) loads
the plugin, as qgis_process does; then `processing.run` runs every algorithm on real surveys of the shared
data, and each result is opened as a QGIS layer and compared with what tinbuild itself says: the CRS
with `tinbuild info --json`, the counts (pixels, tiles, triangles, vertices, contour lines, the water
level) with the run's `--report`.  It also checks the progress the dialog would show, Cancel mid-run
(SIGTERM; no output may be left), the CLI's error message on a bad file, and the messages for an
executable that is missing, not on PATH or too old.

Surveys: laz/Topography.laz (73,403 points, classes 1/2/9, EPSG:2949, lakes), laz/Megaplot.laz (EPSG:26917),
laz/simple.laz (no CRS: the CRS override), edge/1.2-no-points.las (a damaged file); and a 2M-point survey
that `tinbuild demo --survey-only` makes with its river polygon, centreline and road (hydro-flattening
with rivers, and a run long enough to cancel).

Exit 0: every check holds; 1: a check failed (each failure printed); 77: skipped (QGIS's Python bindings,
Debian's python3-qgis, are not installed, or the shared data is absent), which CTest reports as skipped.
"""
import argparse
import glob
import importlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

SKIP = 77
REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
PLUGIN_PATH = os.path.join(REPO, 'share', 'qgis')


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('--tinbuild', required=True, help='the tinbuild executable')
    ap.add_argument('--data', default=os.path.join(os.path.dirname(REPO), 'shared', 'data'),
                    help='the shared real data (../shared/data)')
    ap.add_argument('--workdir', help='scratch folder (default: a new temporary one, removed afterwards)')
    args = ap.parse_args()
    exe = os.path.abspath(args.tinbuild)

    os.environ.setdefault('QT_QPA_PLATFORM', 'offscreen')
    sys.dont_write_bytecode = True   # no __pycache__ in the plugin's source folder
    try:
        importlib.import_module('qgis.core')
    except ImportError as e:
        print(f"skipped: QGIS's Python bindings are not installed ({e}); apt-get install python3-qgis")
        return SKIP
    surveys = {name: os.path.join(args.data, name) for name in
               ('laz/Topography.laz', 'laz/Megaplot.laz', 'laz/simple.laz', 'edge/1.2-no-points.las')}
    missing = [p for p in surveys.values() if not os.path.isfile(p)]
    if missing:
        print(f'skipped: the shared data is absent ({", ".join(missing)}); pass --data DIR')
        return SKIP

    work = args.workdir or tempfile.mkdtemp(prefix='tinbuild-provider-')
    shutil.rmtree(work, ignore_errors=True)
    os.makedirs(work)
    # QGIS's settings (the provider's executable path among them) go to a profile of this run, never to
    # the user's: QSettings follows XDG_CONFIG_HOME, QGIS's own files the profile folder.
    os.environ['XDG_CONFIG_HOME'] = os.path.join(work, 'config')
    try:
        failures = runChecks(exe, surveys, work)
    finally:
        if not args.workdir:
            shutil.rmtree(work, ignore_errors=True)
    print(f'{len(failures)} failed' if failures else 'all provider checks passed')
    return 1 if failures else 0


def runChecks(exe, surveys, work):
    from qgis.core import (QgsApplication, QgsCoordinateReferenceSystem, QgsFeature, QgsGeometry, QgsMeshLayer, QgsPointXY, QgsProcessingException,
                           QgsProcessingFeedback, QgsProject, QgsRasterBandStats, QgsRasterLayer,
                           QgsVectorFileWriter, QgsVectorLayer, QgsWkbTypes)
    QgsApplication.setPrefixPath('/usr', True)
    app = QgsApplication([], False, os.path.join(work, 'profile'))
    app.initQgis()
    sys.path.insert(0, os.path.join(QgsApplication.pkgDataPath(), 'python', 'plugins'))
    from processing.core.Processing import Processing
    from processing.core.ProcessingConfig import ProcessingConfig
    import processing
    import qgis.utils

    failures = []
    started = time.monotonic()

    def check(ok, what):
        print(('ok    ' if ok else 'FAIL  ') + what, flush=True)
        if not ok:
            failures.append(what)
        return ok

    class Feedback(QgsProcessingFeedback):
        """Records what the algorithm dialog would show; cancels once progress reaches cancelAt."""

        def __init__(self, cancelAt=None):
            super().__init__()
            self.progress, self.texts, self.infos, self.commands, self.warnings = [], [], [], [], []
            self.cancelAt, self.cancelledAt = cancelAt, None
            self.progressChanged.connect(self.onProgress)

        def onProgress(self, value):
            self.progress.append(value)
            if self.cancelAt is not None and value >= self.cancelAt and self.cancelledAt is None:
                self.cancelledAt = time.monotonic()
                self.cancel()

        def setProgressText(self, text):
            self.texts.append(text)
            super().setProgressText(text)

        def pushInfo(self, info):
            self.infos.append(info)

        def pushCommandInfo(self, info):
            self.commands.append(info)

        def pushWarning(self, warning):
            self.warnings.append(warning)

    def run(alg, params, feedback=None):
        t = time.monotonic()
        feedback = feedback or Feedback()
        result = processing.run(alg, params, feedback=feedback)
        print(f'      {alg} ran in {time.monotonic() - t:.2f} s', flush=True)
        return result, feedback

    def runFails(alg, params, feedback=None):
        """The QgsProcessingException's message, or None when the run succeeded."""
        try:
            processing.run(alg, params, feedback=feedback or Feedback())
        except QgsProcessingException as e:
            return str(e)
        return None

    def tinbuildInfo(path, *extra):
        r = subprocess.run([exe, 'info', path, '--json', *extra], capture_output=True, text=True, check=True)
        return json.loads(r.stdout)

    def readText(path):
        if not os.path.isfile(path):
            return ''
        with open(path, encoding='utf-8') as f:
            return f.read()

    def report(path):
        with open(path, encoding='utf-8') as f:
            return json.load(f)

    def crsOf(info):
        return QgsCoordinateReferenceSystem(f"EPSG:{info['crs']['epsg']}")

    def leftovers(folder):
        return sorted(os.path.basename(p) for p in glob.glob(os.path.join(folder, '*')) +
                      glob.glob(os.path.join(folder, '.*')))

    # -- the plugin, through QGIS's plugin machinery (as qgis_process loads it) --------------------------
    Processing.initialize()
    # QGIS names a loaded file after the file by default (a fresh profile); the layers' own names are
    # checked here, the same on every machine.
    ProcessingConfig.setSettingValue('PREFER_FILENAME_AS_LAYER_NAME', False)
    qgis.utils.plugin_paths = [PLUGIN_PATH]
    sys.path.insert(0, PLUGIN_PATH)   # as QGIS does for each plugin folder
    qgis.utils.updateAvailablePlugins()
    check('tinbuild_processing' in qgis.utils.available_plugins,
          f'QGIS finds the plugin in {PLUGIN_PATH} (available: {qgis.utils.available_plugins})')
    meta = {k: qgis.utils.pluginMetadata('tinbuild_processing', k) for k in
            ('name', 'qgisMinimumVersion', 'description', 'about', 'version', 'author', 'email',
             'hasProcessingProvider', 'icon')}
    check(all(v and v != '__error__' for v in meta.values()),
          f'metadata.txt has every field QGIS reads ({", ".join(k for k, v in meta.items() if v == "__error__") or "all"})')
    check(meta['qgisMinimumVersion'] == '3.22' and meta['hasProcessingProvider'] == 'yes',
          f"metadata.txt: qgisMinimumVersion {meta['qgisMinimumVersion']}, hasProcessingProvider "
          f"{meta['hasProcessingProvider']}")
    check(os.path.isfile(os.path.join(PLUGIN_PATH, 'tinbuild_processing', meta['icon'])), 'the icon is there')
    check(qgis.utils.loadPlugin('tinbuild_processing') and qgis.utils.startProcessingPlugin('tinbuild_processing'),
          'qgis.utils loads the plugin and starts its Processing part (classFactory(None), initProcessing)')
    provider = QgsApplication.processingRegistry().providerById('tinbuild')
    check(provider is not None, 'the provider tinbuild is registered')
    if provider is None:
        app.exitQgis()
        return failures
    ids = sorted(a.id() for a in provider.algorithms())
    check(ids == ['tinbuild:builddem', 'tinbuild:buildtin', 'tinbuild:contours', 'tinbuild:hydroflatten',
                  'tinbuild:hydrology', 'tinbuild:info'], f'its algorithms: {ids}')
    check(all(len(a.shortHelpString()) > 200 for a in provider.algorithms()), 'each has help text')
    dem = QgsApplication.processingRegistry().algorithmById('tinbuild:builddem')
    names = [p.name() for p in dem.parameterDefinitions()]
    check(all(n in names for n in ('INPUT', 'STEP', 'KEEP_CLASSES', 'OUTPUT')) and
          dem.outputDefinition('OUTPUT') is not None, f'builddem has INPUT, STEP, KEEP_CLASSES, OUTPUT ({names})')
    check(dem.parameterDefinition('KEEP_CLASSES').defaultValue() == [2, 9]
          and dem.parameterDefinition('STEP').defaultValue() == 1.0,
          'builddem keeps ground and water and makes 1 m pixels by default')
    check('TINBUILD_EXECUTABLE' in ProcessingConfig.settings, "the executable's setting is in Processing's options")
    zipped = os.path.join(work, 'zip')
    made = subprocess.run(['bash', os.path.join(PLUGIN_PATH, 'make-zip.sh'), zipped], capture_output=True, text=True)
    if check(made.returncode == 0, f'share/qgis/make-zip.sh builds the zip ({made.stderr.strip()})'):
        import zipfile
        with zipfile.ZipFile(os.path.join(zipped, 'tinbuild_processing.zip')) as z:
            z.extractall(os.path.join(zipped, 'plugins'))
            names = z.namelist()
        found = dict(qgis.utils.findPlugins(os.path.join(zipped, 'plugins')))
        check(all(n.startswith('tinbuild_processing/') and '__pycache__' not in n for n in names)
              and 'tinbuild_processing/metadata.txt' in names and 'tinbuild_processing/icon.svg' in names
              and list(found) == ['tinbuild_processing']
              and found['tinbuild_processing'].get('general', 'hasProcessingProvider') == 'yes',
              f'the zip unpacks to one plugin folder that QGIS recognises ({len(names)} files)')

    # -- finding the executable ---------------------------------------------------------------------------
    topo = surveys['laz/Topography.laz']
    infoParams = {'INPUT': [topo], 'OUTPUT_HTML_FILE': os.path.join(work, 'unused.html')}
    gone = os.path.join(work, 'gone', 'tinbuild')
    os.makedirs(os.path.dirname(gone))
    shutil.copy(exe, gone)
    ProcessingConfig.setSettingValue('TINBUILD_EXECUTABLE', gone)
    os.remove(gone)
    msg = runFails('tinbuild:info', infoParams) or ''
    check('not there' in msg and gone in msg and 'Settings > Options > Processing' in msg,
          f'a setting naming a missing file says so: {msg[:110]}...')
    old = os.path.join(work, 'old', 'tinbuild')
    os.makedirs(os.path.dirname(old))
    with open(old, 'w') as f:
        f.write('#!/bin/sh\necho "tinbuild 0.0.9"\n')
    os.chmod(old, 0o755)
    ProcessingConfig.setSettingValue('TINBUILD_EXECUTABLE', old)
    msg = runFails('tinbuild:info', infoParams) or ''
    check('too old' in msg and '0.0.9' in msg and '0.1.0' in msg, f'a tinbuild older than 0.1.0 is refused: {msg[:100]}...')
    ProcessingConfig.setSettingValue('TINBUILD_EXECUTABLE', '')
    path = os.environ.get('PATH', '')
    empty = os.path.join(work, 'emptybin')
    os.makedirs(empty)
    os.environ['PATH'] = empty
    msg = runFails('tinbuild:info', infoParams) or ''
    check('not found' in msg and 'PATH' in msg, f'no setting and no tinbuild on PATH says so: {msg[:100]}...')
    bindir = os.path.join(work, 'bin')
    os.makedirs(bindir)
    os.symlink(exe, os.path.join(bindir, 'tinbuild'))
    os.environ['PATH'] = bindir + os.pathsep + path
    check(runFails('tinbuild:info', infoParams) is None, 'with the setting empty, the tinbuild on PATH runs')
    os.environ['PATH'] = path
    ProcessingConfig.setSettingValue('TINBUILD_EXECUTABLE', exe)
    check(ProcessingConfig.getSetting('TINBUILD_EXECUTABLE') == exe, f'the setting names {exe}')

    # -- info ----------------------------------------------------------------------------------------------
    topoInfo = tinbuildInfo(topo)
    topoCrs = crsOf(topoInfo)
    html = os.path.join(work, 'info', 'topography.html')
    r, fb = run('tinbuild:info', {'INPUT': [topo], 'OUTPUT_HTML_FILE': html,
                                  'OUTPUT_JSON': os.path.join(work, 'info', 'topography.json')})
    page = readText(html)
    check(r['OUTPUT_HTML_FILE'] == html and '<table>' in page, f'info writes its HTML report ({len(page)} bytes)')
    check(r['POINTS'] == topoInfo['points'] == 73403 and r['CRS_AUTHID'] == topoCrs.authid() == 'EPSG:2949',
          f"info returns {r['POINTS']} points and {r['CRS_AUTHID']} (tinbuild info: {topoInfo['points']}, "
          f"EPSG:{topoInfo['crs']['epsg']})")
    check('NAD83(CSRS) / MTM zone 7' in page and '73,403' in page and 'Ground' in page and '8,159' in page,
          'the report names the CRS, the points and the ground class count')
    check(report(r['OUTPUT_JSON']) == topoInfo, 'its JSON is tinbuild info --json')
    alg = QgsApplication.processingRegistry().algorithmById('tinbuild:info')
    check(type(alg.outputDefinition('OUTPUT_HTML_FILE')).__name__ == 'QgsProcessingOutputHtml',
          'the HTML is an HTML output (shown in the results viewer)')

    # -- builddem: one GeoTIFF with hillshade and slope, the default classes ---------------------------
    out = os.path.join(work, 'dem')
    r, fb = run('tinbuild:builddem', {'INPUT': [topo], 'STEP': 1, 'HILLSHADE': True, 'SLOPE': True,
                                      'OUTPUT': os.path.join(out, 'topography.tif')})
    rep = report(r['REPORT'])
    check(r['REPORT'] == os.path.join(out, 'topography.report.json'), f"the report is kept beside the DEM ({r['REPORT']})")
    kept = topoInfo['classes']['2'] + topoInfo['classes']['9']
    check(rep['points_streamed'] == kept == r['POINTS'],
          f"the default classes are ground and water: {rep['points_streamed']} points streamed, info's classes 2+9 = {kept}")
    check(len(fb.progress) >= 3 and fb.progress[-1] == 100 and fb.progress == sorted(fb.progress),
          f'progress reaches the bar: {len(fb.progress)} updates, {fb.progress[:6]}...')
    check(any(t.startswith('pass 3: streaming chunks') for t in fb.texts), f'the stages reach the progress text ({fb.texts})')
    check(any('--progress json' in c and '--keep-class 2,9' in c for c in fb.commands), 'the command line is logged')
    check(any(i.startswith('tinbuild build:') for i in fb.infos), "tinbuild's summary reaches the log")
    for key, what in (('OUTPUT', 'DEM'), ('OUTPUT_HILLSHADE', 'hillshade'), ('OUTPUT_SLOPE', 'slope')):
        layer = QgsRasterLayer(r[key] or '', what, 'gdal')
        if check(layer.isValid(), f'the {what} {r[key]} opens as a raster layer'):
            check(layer.crs() == topoCrs, f'the {what} CRS {layer.crs().authid()} is the survey\'s {topoCrs.authid()}')
            check((layer.width(), layer.height()) == (rep['dem']['width'], rep['dem']['height']),
                  f"the {what} is {layer.width()} x {layer.height()}, the report {rep['dem']['width']} x {rep['dem']['height']}")
            if key == 'OUTPUT':
                stats = layer.dataProvider().bandStatistics(1, QgsRasterBandStats.All)
                zmin, zmax = topoInfo['bounds']['min'][2], topoInfo['bounds']['max'][2]
                check(stats.elementCount == rep['dem']['pixels_written'],
                      f"the DEM has {stats.elementCount} pixels with a value, the report {rep['dem']['pixels_written']}")
                check(zmin - 1e-3 <= stats.minimumValue < stats.maximumValue <= zmax + 1e-3,
                      f'its heights {stats.minimumValue:.2f} .. {stats.maximumValue:.2f} lie in the survey\'s z range')
    check(r['OUTPUT_ASPECT'] is None, 'no aspect raster was asked for, none is returned')

    # -- builddem: tiles and their VRT from a folder ---------------------------------------------------
    folder = os.path.join(work, 'survey-folder')
    os.makedirs(folder)
    os.symlink(topo, os.path.join(folder, 'Topography.laz'))
    tiles = os.path.join(work, 'tiles', 'topography')
    r, fb = run('tinbuild:builddem', {'INPUT_FOLDER': folder, 'KEEP_CLASSES': [2], 'STEP': 0.5, 'TILE_SIZE_M': 100,
                                      'HILLSHADE': True, 'OUTPUT_TILES': tiles})
    rep = report(r['REPORT'])
    check(r['OUTPUT'] == os.path.join(tiles, 'mosaic.vrt') and r['REPORT'] == tiles + '.report.json',
          f"the tiles' result is their mosaic {r['OUTPUT']}, the report beside the folder")
    check(rep['points_streamed'] == topoInfo['classes']['2'], f"KEEP_CLASSES [2] keeps {rep['points_streamed']} ground points")
    layer = QgsRasterLayer(r['OUTPUT'], 'mosaic', 'gdal')
    if check(layer.isValid(), 'the mosaic opens as a raster layer'):
        check(layer.crs() == topoCrs, f'the mosaic CRS {layer.crs().authid()} is {topoCrs.authid()}')
        check((layer.width(), layer.height()) == (rep['dem']['width'], rep['dem']['height']),
              f"the mosaic is {layer.width()} x {layer.height()}, the report {rep['dem']['width']} x {rep['dem']['height']}")
    n = len(glob.glob(os.path.join(tiles, 'dem_*.tif')))
    check(n == rep['dem']['tiles_written'] > 1, f"{n} DEM tiles, the report {rep['dem']['tiles_written']}")
    check(r['OUTPUT_HILLSHADE'] == os.path.join(tiles, 'hillshade.vrt') and
          QgsRasterLayer(r['OUTPUT_HILLSHADE'], 'h', 'gdal').isValid(), 'the hillshade mosaic opens')

    # -- builddem: the CRS override on a survey without one --------------------------------------------
    simple = surveys['laz/simple.laz']
    check(tinbuildInfo(simple)['crs']['epsg'] is None, 'laz/simple.laz declares no CRS')
    r, fb = run('tinbuild:builddem', {'INPUT': [simple], 'KEEP_CLASSES': [], 'STEP': 2, 'CRS': 'EPSG:2994',
                                      'OUTPUT': os.path.join(work, 'crs', 'simple.tif')})
    layer = QgsRasterLayer(r['OUTPUT'], 'simple', 'gdal')
    check(layer.isValid() and layer.crs().authid() == 'EPSG:2994', f'the assigned CRS is the DEM\'s ({layer.crs().authid()})')
    check(report(r['REPORT'])['points_streamed'] == 1065, 'no classes chosen keeps every point but noise (1065)')
    r2, _ = run('tinbuild:info', {'INPUT': [simple], 'CRS': 'EPSG:2994', 'OUTPUT_HTML_FILE': os.path.join(work, 'crs', 'i.html')})
    check(r2['CRS_AUTHID'] == 'EPSG:2994', f"info with the CRS assigned says {r2['CRS_AUTHID']}")

    # -- buildtin: GeoPackage layer and UGRID mesh ------------------------------------------------------
    mega = surveys['laz/Megaplot.laz']
    megaCrs = crsOf(tinbuildInfo(mega))
    r, fb = run('tinbuild:buildtin', {'INPUT': [mega], 'KEEP_CLASSES': [2], 'OUTPUT': os.path.join(work, 'tin', 'megaplot.gpkg'),
                                      'OUTPUT_MESH': os.path.join(work, 'tin', 'megaplot.nc')})
    rep = report(r['REPORT'])
    tri, ver = rep['triangulation']['triangles'], rep['triangulation']['vertices']
    check(r['TRIANGLES'] == tri and r['VERTICES'] == ver and tri > 10000, f'buildtin returns {tri} triangles, {ver} vertices')
    tin = QgsVectorLayer(r['OUTPUT'] + '|layername=tin', 'tin', 'ogr')
    if check(tin.isValid(), 'the GeoPackage TIN opens as a vector layer'):
        check(tin.crs() == megaCrs, f'its CRS {tin.crs().authid()} is the survey\'s {megaCrs.authid()}')
        check(tin.featureCount() == tri, f'it holds {tin.featureCount()} triangles, the report {tri}')
        check(QgsWkbTypes.hasZ(tin.wkbType()) and tin.geometryType() == QgsWkbTypes.PolygonGeometry, 'of 3D polygons')
    mesh = QgsMeshLayer(r['OUTPUT_MESH'], 'mesh', 'mdal')
    if check(mesh.isValid(), 'the UGRID mesh opens as a mesh layer'):
        check(mesh.crs() == megaCrs, f'its CRS {mesh.crs().authid()} is {megaCrs.authid()}')
        dp = mesh.dataProvider()
        check((dp.faceCount(), dp.vertexCount()) == (tri, ver),
              f'it has {dp.faceCount()} faces and {dp.vertexCount()} vertices, the report {tri} and {ver}')

    # -- contours -------------------------------------------------------------------------------------------
    r, fb = run('tinbuild:contours', {'INPUT': [topo], 'INTERVAL': 1, 'INDEX_EVERY': 5, 'SIMPLIFY': 0.2,
                                      'OUTPUT': os.path.join(work, 'contours', 'topography.gpkg')})
    rep = report(r['REPORT'])
    iso = QgsVectorLayer(r['OUTPUT'] + '|layername=contours', 'contours', 'ogr')
    if check(iso.isValid(), 'the contours open as a vector layer'):
        check(iso.crs() == topoCrs, f'their CRS {iso.crs().authid()} is {topoCrs.authid()}')
        check(iso.featureCount() == rep['contours']['lines'] == r['LINES'] > 50,
              f"{iso.featureCount()} lines, the report {rep['contours']['lines']}")
        elevs = [(f['elev'], f['index']) for f in iso.getFeatures()]
        check(all(abs(e - round(e)) < 1e-9 for e, _ in elevs), 'every level is a multiple of the 1 m interval')
        check(all(bool(i) == (round(e) % 5 == 0) for e, i in elevs) and any(i for _, i in elevs),
              'index contours are the levels at multiples of 5 m')
        check(rep['contours']['simplify'] == 0.2 and rep['contours']['simplified_away'] > 0, 'the lines were simplified')

    # -- hydroflatten on the real survey: a lake from a memory layer, a breakline from a GeoPackage ---
    hydro = os.path.join(work, 'hydro')
    os.makedirs(hydro)
    lake = QgsVectorLayer('Polygon?crs=EPSG:2949', 'lake', 'memory')
    ring = [(273437, 5274578), (273507, 5274578), (273507, 5274603), (273437, 5274603)]
    f = QgsFeature()
    f.setGeometry(QgsGeometry.fromPolygonXY([[QgsPointXY(x, y) for x, y in ring]]))
    lake.dataProvider().addFeatures([f])
    QgsProject.instance().addMapLayer(lake)
    brk = os.path.join(hydro, 'breakline.gpkg')
    line = QgsVectorLayer('LineStringZ?crs=EPSG:2949', 'breakline', 'memory')
    g = QgsFeature()
    g.setGeometry(QgsGeometry.fromWkt('LineStringZ (273380 5274380 812, 273600 5274450 815)'))
    line.dataProvider().addFeatures([g])
    opts = QgsVectorFileWriter.SaveVectorOptions()
    opts.driverName = 'GPKG'
    QgsVectorFileWriter.writeAsVectorFormatV3(line, brk, QgsProject.instance().transformContext(), opts)
    r, fb = run('tinbuild:hydroflatten', {'INPUT': [topo], 'STEP': 1, 'WATER': [lake.id()], 'BREAKLINES': [brk],
                                          'OUTPUT': os.path.join(hydro, 'topography.tif'),
                                          'OUTPUT_TIN': os.path.join(hydro, 'topography.gpkg')})
    rep = report(r['REPORT'])
    cons = rep.get('constraints', {})
    check(any('lake' in i and 'written to' in i for i in fb.infos) and any(brk in c for c in fb.commands),
          'the memory layer went to tinbuild as a temporary GeoPackage, the GeoPackage layer as it is')
    check(cons.get('breaklines') == 1 and cons.get('pieces', 0) > 0 and len(cons.get('water', [])) == 1
          and cons['water'][0]['kind'] == 'lake', f"the report has the breakline and the lake ({cons.get('water')})")
    layer = QgsRasterLayer(r['OUTPUT'], 'hydro', 'gdal')
    if check(layer.isValid() and layer.crs() == topoCrs, 'the hydro-flattened DEM opens with its CRS') and cons.get('water'):
        level = cons['water'][0]['level']
        inside = [layer.dataProvider().sample(QgsPointXY(x + 0.5, y + 0.5), 1)[0]
                  for x in range(273439, 273505, 3) for y in range(5274580, 5274601, 3)]
        check(max(abs(v - level) for v in inside) < 1e-3,
              f'the lake is flat at its level {level:.3f} ({len(inside)} pixels, {min(inside):.3f} .. {max(inside):.3f})')
    tin = QgsVectorLayer((r['OUTPUT_TIN'] or '') + '|layername=tin', 'tin', 'ogr')
    check(tin.isValid() and tin.crs() == topoCrs and tin.featureCount() == rep['triangulation']['triangles'],
          f"the hydro-flattened TIN opens with {tin.crs().authid()} and {tin.featureCount()} triangles (report "
          f"{rep['triangulation']['triangles']})")
    QgsProject.instance().removeMapLayer(lake.id())
    # An empty water layer is named as the user's layer, before any work (not as the temporary GeoPackage
    # it would be written to).
    dry = QgsVectorLayer('Polygon?crs=EPSG:2949', 'dry pond', 'memory')
    QgsProject.instance().addMapLayer(dry)
    msg = runFails('tinbuild:hydroflatten', {'INPUT': [topo], 'STEP': 1, 'WATER': [dry.id()],
                                             'OUTPUT': os.path.join(hydro, 'dry.tif')}) or ''
    check('dry pond' in msg and 'has no features' in msg and 'tinbuild-' not in msg and
          not os.path.exists(os.path.join(hydro, 'dry.tif')),
          f'an empty water layer is refused by its name: {msg!r}')
    QgsProject.instance().removeMapLayer(dry.id())

    # -- hydroflatten with a river (the demo's polygon, centreline and road), and a TIN ---------------
    demo = os.path.join(work, 'demo')
    subprocess.run([exe, 'demo', demo, '--points', '2', '--survey-only', '--progress', 'none'], check=True,
                   capture_output=True)
    survey = os.path.join(demo, 'survey.laz')
    r, fb = run('tinbuild:hydroflatten', {'INPUT': [survey], 'STEP': 2, 'WATER': [os.path.join(demo, 'water.geojson')],
                                          'FLOW': [os.path.join(demo, 'flow.geojson')],
                                          'BREAKLINES': [os.path.join(demo, 'roads.geojson')],
                                          'OUTPUT': os.path.join(hydro, 'river.tif')})
    rep = report(r['REPORT'])
    water = rep.get('constraints', {}).get('water', [])
    check(len(water) == 1 and water[0]['kind'] == 'river' and water[0]['stations'] > 0,
          f"the polygon crossed by the centreline is a river ({[(w['kind'], w['stations']) for w in water]} stations)")
    layer = QgsRasterLayer(r['OUTPUT'], 'river', 'gdal')
    if check(layer.isValid() and layer.crs().authid() == 'EPSG:32610', 'the river DEM opens with EPSG:32610'):
        # Along the centreline, inside the DEM, the river never rises downstream.
        centre = QgsVectorLayer(os.path.join(demo, 'flow.geojson'), 'flow', 'ogr')
        g = next(centre.getFeatures()).geometry()
        e = layer.extent()
        values = []
        for i in range(int(g.length())):
            p = g.interpolate(float(i)).asPoint()
            if e.xMinimum() + 10 < p.x() < e.xMaximum() - 10 and e.yMinimum() + 10 < p.y() < e.yMaximum() - 10:
                v, ok = layer.dataProvider().sample(QgsPointXY(p), 1)
                if ok:
                    values.append(v)
        rises = sum(1 for a, b in zip(values, values[1:]) if b > a + 1e-4)
        check(len(values) > 100 and rises == 0,
              f'the river never rises along its centreline ({len(values)} samples, {rises} rises)')

    # -- hydrology on the river DEM: HAND, streams, a flood; loaded and styled --------------------------
    if os.path.exists(os.path.join(hydro, 'river.tif')):
        riverDem = QgsRasterLayer(os.path.join(hydro, 'river.tif'), 'river dem', 'gdal')
        QgsProject.instance().addMapLayer(riverDem)
        folder = os.path.join(work, 'hydrology')
        fb = Feedback()
        r = processing.runAndLoadResults('tinbuild:hydrology', {
            'DEM': riverDem.id(), 'STREAM_AREA': 2, 'STAGE': 1.5, 'FLOW': [os.path.join(demo, 'flow.geojson')],
            'OUTPUT_FOLDER': folder}, feedback=fb)
        rep = report(r['REPORT'])
        check(rep.get('streams', {}).get('links', 0) > 0 and rep.get('drainage', {}).get('flooded_cells', 0) > 0
              and rep.get('breach', {}).get('flow_lines') == 1,
              f"hydrology: links {rep.get('streams', {}).get('links')}, flooded cells "
              f"{rep.get('drainage', {}).get('flooded_cells')}, the centreline breached")
        check(fb.progress and max(fb.progress) >= 99, f'hydrology drives the progress bar (up to {max(fb.progress or [0])})')
        loadedHydro = {l.name(): l for l in QgsProject.instance().mapLayers().values()
                       if l.source().startswith(folder)}
        check(sorted(loadedHydro) == ['Flood depth', 'Flood extent', 'HAND', 'Streams']
              and all(l.isValid() and l.crs().authid() == 'EPSG:32610' for l in loadedHydro.values()),
              f'HAND, the streams, the depth and the flood are loaded with the DEM\'s CRS ({sorted(loadedHydro)})')
        hand = loadedHydro.get('HAND')
        if hand is not None:
            check(hand.renderer().type() == 'singlebandpseudocolor', 'HAND is styled with a colour ramp')
            stats = hand.dataProvider().bandStatistics(1, QgsRasterBandStats.Min | QgsRasterBandStats.Max)
            check(stats.minimumValue == 0 and stats.maximumValue > 1, f'HAND runs from 0 ({stats.minimumValue}, {stats.maximumValue})')
        streams = loadedHydro.get('Streams')
        if streams is not None:
            check(streams.featureCount() == rep['streams']['links'] and
                  streams.geometryType() == QgsWkbTypes.LineGeometry and 'strahler' in streams.fields().names(),
                  f'one stream line per link with its Strahler order ({streams.featureCount()})')
        msg = runFails('tinbuild:hydrology', {'DEM': os.path.join(work, 'nowhere.tif'), 'OUTPUT_FOLDER': folder + '2'})
        check(msg is not None and not os.path.exists(folder + '2'), f'a missing DEM is refused: {msg!r}')
        for l in list(loadedHydro.values()) + [riverDem]:
            QgsProject.instance().removeMapLayer(l.id())

    # -- results loaded into the project on completion (what the dialog does) ----------------------------
    project = QgsProject.instance()
    project.removeAllMapLayers()
    loaded = os.path.join(work, 'loaded')
    processing.runAndLoadResults('tinbuild:builddem', {'INPUT': [topo], 'HILLSHADE': True, 'SLOPE': True,
                                                       'OUTPUT': os.path.join(loaded, 'dem.tif')}, feedback=Feedback())
    processing.runAndLoadResults('tinbuild:builddem', {'INPUT': [topo], 'STEP': 2, 'HILLSHADE': True,
                                                       'OUTPUT_TILES': os.path.join(loaded, 'tiles')}, feedback=Feedback())
    processing.runAndLoadResults('tinbuild:buildtin', {'INPUT': [mega], 'OUTPUT': os.path.join(loaded, 'tin.gpkg'),
                                                       'OUTPUT_MESH': os.path.join(loaded, 'tin.nc')}, feedback=Feedback())
    processing.runAndLoadResults('tinbuild:contours', {'INPUT': [topo], 'OUTPUT': os.path.join(loaded, 'contours.gpkg')},
                                 feedback=Feedback())
    layers = sorted(((l.name(), type(l).__name__, l.crs().authid(), l.isValid(), os.path.basename(l.source().split('|')[0]))
                     for l in project.mapLayers().values()))
    print(f'      loaded: {layers}')
    want = sorted([('DEM', 'QgsRasterLayer', 'EPSG:2949', True, 'dem.tif'),
                   ('Hillshade', 'QgsRasterLayer', 'EPSG:2949', True, 'dem_hillshade.tif'),
                   ('Slope', 'QgsRasterLayer', 'EPSG:2949', True, 'dem_slope.tif'),
                   ('DEM', 'QgsRasterLayer', 'EPSG:2949', True, 'mosaic.vrt'),
                   ('Hillshade', 'QgsRasterLayer', 'EPSG:2949', True, 'hillshade.vrt'),
                   ('TIN', 'QgsVectorLayer', 'EPSG:26917', True, 'tin.gpkg'),
                   ('TIN mesh', 'QgsMeshLayer', 'EPSG:26917', True, 'tin.nc'),
                   ('Contours', 'QgsVectorLayer', 'EPSG:2949', True, 'contours.gpkg')])
    check(layers == want, 'the results are loaded into the project as raster, vector and mesh layers with their CRS')
    from qgis.PyQt.QtGui import QPainter
    byName = {}
    for layer in project.mapLayers().values():
        byName.setdefault(layer.name(), []).append(layer)
    check(len(byName.get('DEM', [])) == 2 and len(byName.get('Hillshade', [])) == 2 and
          all(l.renderer().type() == 'singlebandpseudocolor' for l in byName['DEM']) and
          all(l.blendMode() == QPainter.CompositionMode_Multiply for l in byName['Hillshade']),
          'the loaded DEMs are coloured by height and their hillshades multiplied over them')
    project.removeAllMapLayers()

    # -- Cancel mid-run: SIGTERM, no output left ---------------------------------------------------------
    cancel = os.path.join(work, 'cancel')
    os.makedirs(cancel)
    fb = Feedback(cancelAt=60)   # pass 3 (the triangulation and the DEM) starts at 66.7 %
    t = time.monotonic()
    msg = runFails('tinbuild:builddem', {'INPUT': [survey], 'STEP': 0.5, 'HILLSHADE': True, 'THREADS': 1,
                                         'OUTPUT_TILES': os.path.join(cancel, 'tiles')}, fb) or ''
    stopped = time.monotonic()
    check(fb.cancelledAt is not None, f'the run was cancelled at {fb.progress[-1] if fb.progress else "?"} %')
    check('Cancelled' in msg and 'no output' in msg, f'the algorithm raised: {msg}')
    check(fb.cancelledAt is not None and stopped - fb.cancelledAt < 5,
          f'tinbuild stopped {stopped - (fb.cancelledAt or stopped):.2f} s after Cancel (run {stopped - t:.2f} s)')
    check(leftovers(cancel) == [], f'nothing is left where the outputs were to go: {leftovers(cancel)}')
    fb = Feedback(cancelAt=60)
    msg = runFails('tinbuild:buildtin', {'INPUT': [survey], 'THREADS': 1, 'OUTPUT': os.path.join(cancel, 'tin.gpkg'),
                                         'OUTPUT_MESH': os.path.join(cancel, 'tin.nc')}, fb) or ''
    check('Cancelled' in msg and leftovers(cancel) == [],
          f'a cancelled TIN leaves no GeoPackage, mesh or report either: {leftovers(cancel)}')

    # -- a bad file: the CLI's error ------------------------------------------------------------------------
    bad = surveys['edge/1.2-no-points.las']
    badOut = os.path.join(work, 'bad')
    os.makedirs(badOut)
    msg = runFails('tinbuild:builddem', {'INPUT': [bad], 'OUTPUT': os.path.join(badOut, 'dem.tif')}) or ''
    check(msg.startswith('tinbuild: error:') and '1.2-no-points.las' in msg and 'exit code 1' in msg,
          f"a damaged file gives tinbuild's message: {msg!r}")
    check(leftovers(badOut) == [], 'and leaves no output')
    msg = runFails('tinbuild:builddem', {'STEP': 1, 'OUTPUT': os.path.join(badOut, 'dem.tif')}) or ''
    check('Choose point cloud files' in msg, f'no input is refused before the run: {msg!r}')

    print(f'      provider checks took {time.monotonic() - started:.1f} s')
    from qgis.core import QgsProcessingUtils
    shutil.rmtree(QgsProcessingUtils.tempFolder(), ignore_errors=True)   # this run's Processing scratch
    app.exitQgis()
    return failures


if __name__ == '__main__':
    code = main()
    sys.stdout.flush()
    sys.stderr.flush()
    # PyQGIS may crash while the interpreter tears its objects down after exitQgis(); the checks are
    # done and reported, so leave without that teardown.
    os._exit(code)
