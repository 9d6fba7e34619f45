#!/usr/bin/python3
"""Renders the QGIS screenshots of docs/usage.md, headless (Qt's offscreen platform, no display):

- docs/images/qgis-builddem-dialog.png: the Processing dialog of tinbuild:builddem, filled in;
- docs/images/qgis-builddem-log.png: the same dialog after the run, on its Log tab;
- docs/images/qgis-dem.png: the DEM that the algorithm made, loaded the way the dialog loads it (coloured
  by height, its hillshade multiplied over it) with tinbuild:contours' lines, drawn by QGIS's map renderer.

    QT_QPA_PLATFORM=offscreen /usr/bin/python3 share/qgis/make-screenshots.py --tinbuild build/tinbuild

The survey is ../shared/data/laz/Topography.laz (read in place).  The outputs go to a scratch folder;
only the PNGs are written into --out (default docs/images).  Needs python3-qgis (share/install-deps.sh).
QGIS 3.22's dialog cannot take a preset list of files (its multiple-file widget tries to open them as
layers), so the dialog is given the survey's folder (INPUT_FOLDER), which the algorithm also accepts.
"""
import argparse
import os
import shutil
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(os.path.dirname(HERE))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('--tinbuild', required=True, help='the tinbuild executable')
    ap.add_argument('--data', default=os.path.join(os.path.dirname(REPO), 'shared', 'data'))
    ap.add_argument('--out', default=os.path.join(REPO, 'docs', 'images'))
    args = ap.parse_args()
    exe = os.path.abspath(args.tinbuild)
    topo = os.path.join(args.data, 'laz', 'Topography.laz')
    out = os.path.abspath(args.out)
    os.makedirs(out, exist_ok=True)

    # A fixed scratch folder, so that the paths the dialog shows stay the same from one rendering to the next.
    work = os.path.join(tempfile.gettempdir(), 'tinbuild-qgis-screenshots')
    shutil.rmtree(work, ignore_errors=True)
    os.makedirs(work)
    os.environ.setdefault('QT_QPA_PLATFORM', 'offscreen')
    sys.dont_write_bytecode = True   # no __pycache__ in the plugin's source folder
    os.environ['XDG_CONFIG_HOME'] = os.path.join(work, 'config')   # QGIS settings of this run only
    try:
        return render(exe, topo, work, out)
    finally:
        shutil.rmtree(work, ignore_errors=True)


def savePng(image, path, photo=False):
    """256 colours: dithered for a map, plain for a dialog (a third to a fifth of the bytes)."""
    from qgis.PyQt.QtCore import Qt
    from qgis.PyQt.QtGui import QImage
    flags = (Qt.DiffuseDither | Qt.PreferDither) if photo else (Qt.ThresholdDither | Qt.AvoidDither)
    image.convertToFormat(QImage.Format_Indexed8, flags).save(path)
    print('wrote', path)


def render(exe, topo, work, out):
    from unittest import mock
    from qgis.PyQt.QtCore import QSize, Qt
    from qgis.PyQt.QtGui import QColor, QFont, QPainter
    from qgis.PyQt.QtWidgets import QMainWindow
    from qgis.core import (QgsApplication, QgsLineSymbol, QgsMapRendererParallelJob, QgsMapSettings,
                           QgsProject, QgsProperty, QgsSymbolLayer, QgsSingleSymbolRenderer,
                           QgsProcessingFeedback)
    from qgis.gui import QgisInterface, QgsMapCanvas

    QgsApplication.setPrefixPath('/usr', True)
    app = QgsApplication([], True, os.path.join(work, 'profile'))
    app.initQgis()
    sys.path.insert(0, os.path.join(QgsApplication.pkgDataPath(), 'python', 'plugins'))
    sys.path.insert(0, HERE)

    # The dialog wants QGIS's main window: a stand-in interface with a window and a map canvas.
    import qgis.utils
    iface = mock.Mock(spec=QgisInterface)
    window = QMainWindow()
    canvas = QgsMapCanvas(window)
    iface.mainWindow.return_value = window
    iface.mapCanvas.return_value = canvas

    from processing.core.Processing import Processing
    from processing.core.ProcessingConfig import ProcessingConfig
    import processing
    import processing.tools.general
    # Only createAlgorithmDialog gets it: the panels built inside see no iface, as under qgis_process.
    processing.tools.general.iface = iface
    Processing.initialize()
    qgis.utils.plugin_paths = [HERE]
    qgis.utils.updateAvailablePlugins()
    if not (qgis.utils.loadPlugin('tinbuild_processing') and qgis.utils.startProcessingPlugin('tinbuild_processing')):
        print('cannot load the plugin')
        return 1
    ProcessingConfig.setSettingValue('TINBUILD_EXECUTABLE', exe)
    ProcessingConfig.setSettingValue('PREFER_FILENAME_AS_LAYER_NAME', False)   # the layers' own names

    survey = os.path.join(work, 'survey')
    os.makedirs(survey)
    os.symlink(topo, os.path.join(survey, os.path.basename(topo)))
    results = os.path.join(work, 'results')
    params = {'INPUT_FOLDER': survey, 'STEP': 0.5, 'HILLSHADE': True, 'SLOPE': False,
              'OUTPUT': os.path.join(results, 'topography.tif')}

    # 1. The dialog, filled in.
    dlg = processing.createAlgorithmDialog('tinbuild:builddem', params)
    dlg.resize(1100, 900)
    dlg.show()
    for _ in range(5):
        app.processEvents()
    savePng(dlg.grab().toImage(), os.path.join(out, 'qgis-builddem-dialog.png'))

    # 2. Run it from the dialog (a background task, as when one clicks Run) and show its log.
    dlg.runAlgorithm()
    deadline = time.monotonic() + 120
    while not os.path.exists(os.path.join(results, 'topography.report.json')) and time.monotonic() < deadline:
        app.processEvents()
        time.sleep(0.05)
    end = time.monotonic() + 3
    while time.monotonic() < end:   # the task's finish: results, log, layers loaded
        app.processEvents()
        time.sleep(0.05)
    savePng(dlg.grab().toImage(), os.path.join(out, 'qgis-builddem-log.png'))
    dlg.close()

    # 3. The DEM as the dialog loaded it, with contour lines.
    project = QgsProject.instance()
    processing.runAndLoadResults('tinbuild:contours', {'INPUT': [topo], 'INTERVAL': 1, 'INDEX_EVERY': 5,
                                                       'SIMPLIFY': 0.2, 'OUTPUT': os.path.join(results, 'contours.gpkg')},
                                 feedback=QgsProcessingFeedback())
    layers = {layer.name(): layer for layer in project.mapLayers().values()}
    missing = [n for n in ('DEM', 'Hillshade', 'Contours') if n not in layers]
    if missing:
        print(f'the run did not load {missing} (loaded: {sorted(layers)})')
        return 1
    contours = layers['Contours']
    symbol = QgsLineSymbol.createSimple({'color': '80,50,30,170', 'width': '0.18', 'width_unit': 'MM'})
    symbol.symbolLayer(0).setDataDefinedProperty(
        QgsSymbolLayer.PropertyStrokeWidth, QgsProperty.fromExpression('CASE WHEN "index" THEN 0.45 ELSE 0.18 END'))
    contours.setRenderer(QgsSingleSymbolRenderer(symbol))

    settings = QgsMapSettings()
    settings.setLayers([contours, layers['Hillshade'], layers['DEM']])
    settings.setDestinationCrs(layers['DEM'].crs())
    extent = layers['DEM'].extent()
    extent.scale(1.04)
    settings.setExtent(extent)
    settings.setOutputSize(QSize(900, 900))
    settings.setBackgroundColor(QColor('white'))
    settings.setFlag(QgsMapSettings.Antialiasing, True)
    job = QgsMapRendererParallelJob(settings)
    job.start()
    job.waitForFinished()
    image = job.renderedImage()
    painter = QPainter(image)
    painter.setRenderHint(QPainter.Antialiasing)
    painter.fillRect(0, 868, 900, 32, QColor(255, 255, 255, 215))
    painter.setPen(QColor('black'))
    painter.setFont(QFont('DejaVu Sans', 10))
    painter.drawText(10, 868, 880, 32, Qt.AlignVCenter | Qt.AlignLeft,
                     f"{os.path.basename(topo)} ({layers['DEM'].crs().authid()}): tinbuild:builddem 0.5 m "
                     f"with hillshade, tinbuild:contours every 1 m (index every 5 m)")
    painter.end()
    savePng(image, os.path.join(out, 'qgis-dem.png'), photo=True)
    project.removeAllMapLayers()
    from qgis.core import QgsProcessingUtils
    shutil.rmtree(QgsProcessingUtils.tempFolder(), ignore_errors=True)   # this run's Processing scratch
    app.exitQgis()
    return 0


if __name__ == '__main__':
    code = main()
    sys.stdout.flush()
    os._exit(code)
