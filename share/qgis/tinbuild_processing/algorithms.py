r"""The provider's algorithms: each one a tinbuild command line built from its parameters.

| algorithm | command | outputs (loaded as layers on completion) |
|---|---|---|
| `tinbuild:builddem` | `tinbuild build INPUT... --dem FILE.tif\|DIR --step R` | DEM GeoTIFF, or tiles + mosaic.vrt; hillshade, slope, aspect |
| `tinbuild:hydroflatten` | the same with `--breaklines`, `--water`, `--flow` | hydro-flattened DEM (and its TIN) |
| `tinbuild:buildtin` | `tinbuild build INPUT... --gpkg FILE.gpkg --mesh FILE.nc` | GeoPackage layer `tin`; UGRID mesh |
| `tinbuild:contours` | `tinbuild build INPUT... --contours FILE.gpkg --interval D` | GeoPackage layer `contours` |
| `tinbuild:info` | `tinbuild info INPUT... --json` | HTML report in the results viewer |
| `tinbuild:hydrology` | `tinbuild hydrology DEM -o DIR [--stream-area A] [--stage H] [--flow FILE]` | HAND, streams (lines), flood depth and extent; every raster of the run in DIR |

Conventions shared by all of them:

- Inputs are `INPUT` (one or more point cloud files: LAS, LAZ, COPC, XYZ) and/or `INPUT_FOLDER` (a folder,
  whose *.las, *.laz and *.xyz tinbuild reads); at least one is needed.  `KEEP_CLASSES` is a multiple
  choice of the ASPRS classes 0..18 whose index is the class code (default ground and water, `[2, 9]`);
  an empty choice keeps tinbuild's default (every class but the noise classes 7 and 18).  `CRS` assigns a
  CRS (`--a_srs`), overriding the files'.
- Processing's outputs may always be replaced, so every build gets `--overwrite`.  Every build writes its
  run report (`--report`) beside its first output, named after it (`dem.tif` -> `dem.report.json`, a
  tiles folder `dem/` -> `dem.report.json`: nothing may be written inside a DEM folder), and returns it
  as `REPORT`; its counts come back as numeric results too.
- Vector layers given as constraints are handed to tinbuild as files: a layer that is a whole
  single-layer OGR file without a filter is passed as it is; any other (a memory layer, a filtered
  layer, one layer of a multi-layer GeoPackage, a database layer) is first written to a temporary
  GeoPackage, because tinbuild reads every layer of the files it is given.
"""
import json
import os
import shlex
import tempfile

from qgis.PyQt.QtCore import QCoreApplication
from qgis.PyQt.QtGui import QIcon
from qgis.core import (QgsCoordinateReferenceSystem, QgsProcessing, QgsProcessingAlgorithm,
                       QgsProcessingContext, QgsProcessingException, QgsProcessingOutputFile,
                       QgsProcessingOutputNumber, QgsProcessingOutputRasterLayer, QgsProcessingOutputString,
                       QgsProcessingOutputVectorLayer, QgsProcessingParameterRasterLayer,
                       QgsProcessingParameterBoolean, QgsProcessingParameterCrs, QgsProcessingParameterDefinition,
                       QgsProcessingParameterEnum, QgsProcessingParameterFile,
                       QgsProcessingParameterFileDestination, QgsProcessingParameterFolderDestination,
                       QgsProcessingParameterMultipleLayers, QgsProcessingParameterNumber,
                       QgsProcessingParameterRasterDestination, QgsProcessingParameterString,
                       QgsProcessingParameterVectorDestination, QgsProcessingUtils, QgsProviderRegistry,
                       QgsVectorFileWriter, QgsVectorLayer)

from . import runner, styles
from .info_html import infoHtml

ICON = os.path.join(os.path.dirname(__file__), 'icon.svg')

# ASPRS LAS 1.4 standard classes; the option's index is the class code.
ASPRS_CLASSES = [
    'Created, never classified', 'Unclassified', 'Ground', 'Low vegetation', 'Medium vegetation',
    'High vegetation', 'Building', 'Low point (noise)', 'Model key-point', 'Water', 'Rail',
    'Road surface', 'Overlap', 'Wire guard (shield)', 'Wire conductor (phase)', 'Transmission tower',
    'Wire-structure connector', 'Bridge deck', 'High noise',
]
DEFAULT_CLASSES = [2, 9]


def tr(text):
    return QCoreApplication.translate('tinbuild', text)


def reportPathFor(output):
    """`dem.tif` -> `dem.report.json`; a folder `dem/` -> `dem.report.json` beside it."""
    base = os.path.abspath(output.rstrip('/\\') if len(output) > 1 else output)
    root, ext = os.path.splitext(base)
    return (root if ext else base) + '.report.json'


def crsArgument(crs):
    """What --a_srs gets: `EPSG:n` when QGIS knows the code, else the CRS's WKT2."""
    if crs.authid().upper().startswith('EPSG:'):
        return crs.authid()
    return crs.toWkt(QgsCoordinateReferenceSystem.WKT2_2019)


def advanced(param):
    param.setFlags(param.flags() | QgsProcessingParameterDefinition.FlagAdvanced)
    return param


class TinbuildAlgorithm(QgsProcessingAlgorithm):
    INPUT = 'INPUT'
    INPUT_FOLDER = 'INPUT_FOLDER'
    KEEP_CLASSES = 'KEEP_CLASSES'
    CRS = 'CRS'
    THREADS = 'THREADS'
    EXTRA_OPTIONS = 'EXTRA_OPTIONS'
    REPORT = 'REPORT'
    POINTS = 'POINTS'
    TRIANGLES = 'TRIANGLES'
    VERTICES = 'VERTICES'

    _name = ''
    _displayName = ''
    _group = 'Terrain'
    _groupId = 'terrain'
    _help = ''

    def createInstance(self):
        return type(self)()

    def name(self):
        return self._name

    def displayName(self):
        return tr(self._displayName)

    def group(self):
        return tr(self._group)

    def groupId(self):
        return self._groupId

    def icon(self):
        return QIcon(ICON)

    def shortHelpString(self):
        return tr(self._help) + tr(INPUT_HELP)

    def tags(self):
        return ['lidar', 'las', 'laz', 'point cloud', 'tin', 'dem', 'terrain', 'tinbuild']

    # -- parameters shared by the algorithms ------------------------------------------------------------
    def addInputParameters(self, classes=True):
        self.addParameter(QgsProcessingParameterMultipleLayers(
            self.INPUT, tr('Point cloud files (LAS, LAZ, COPC, XYZ)'), QgsProcessing.TypeFile, optional=True))
        self.addParameter(QgsProcessingParameterFile(
            self.INPUT_FOLDER, tr('or a folder of point cloud files (its *.las, *.laz, *.xyz)'),
            QgsProcessingParameterFile.Folder, optional=True))
        if classes:
            self.addParameter(QgsProcessingParameterEnum(
                self.KEEP_CLASSES, tr('Classes kept (none chosen: all but noise 7 and 18)'),
                [f'{i}: {tr(n)}' for i, n in enumerate(ASPRS_CLASSES)], allowMultiple=True,
                defaultValue=DEFAULT_CLASSES, optional=True))
        self.addParameter(QgsProcessingParameterCrs(
            self.CRS, tr("Assign CRS (overrides the files' CRS; empty: the files')"), optional=True))

    def addAdvancedParameters(self, threads=True):
        if threads:
            self.addParameter(advanced(QgsProcessingParameterNumber(
                self.THREADS, tr('Threads (0: all cores; output is the same for any number)'),
                QgsProcessingParameterNumber.Integer, 0, minValue=0, maxValue=1024)))
        self.addParameter(advanced(QgsProcessingParameterString(
            self.EXTRA_OPTIONS, tr('Additional tinbuild options (as on the command line)'), optional=True)))

    def addReportOutputs(self):
        self.addOutput(QgsProcessingOutputFile(self.REPORT, tr('Run report (JSON)')))
        self.addOutput(QgsProcessingOutputNumber(self.POINTS, tr('Points streamed (after the filters)')))
        self.addOutput(QgsProcessingOutputNumber(self.TRIANGLES, tr('TIN triangles')))
        self.addOutput(QgsProcessingOutputNumber(self.VERTICES, tr('TIN vertices')))

    def checkParameterValues(self, parameters, context):
        ok, message = super().checkParameterValues(parameters, context)
        if not ok:
            return ok, message
        if not self.inputs(parameters, context):
            return False, tr('Choose point cloud files (INPUT) or a folder of them (INPUT_FOLDER).')
        return True, ''

    def inputs(self, parameters, context):
        files = [f for f in self.parameterAsFileList(parameters, self.INPUT, context) if f]
        folder = self.parameterAsFile(parameters, self.INPUT_FOLDER, context) \
            if self.INPUT_FOLDER in parameters else ''
        return files + ([folder] if folder else [])

    def inputArgs(self, parameters, context):
        inputs = self.inputs(parameters, context)
        if not inputs:
            raise QgsProcessingException(tr('Choose point cloud files (INPUT) or a folder of them (INPUT_FOLDER).'))
        args = [os.path.abspath(i) for i in inputs]
        crs = self.parameterAsCrs(parameters, self.CRS, context)
        if crs.isValid():
            args += ['--a_srs', crsArgument(crs)]
        return args

    def filterArgs(self, parameters, context):
        args = []
        if self.parameterDefinition(self.KEEP_CLASSES) is not None:
            classes = sorted(set(self.parameterAsEnums(parameters, self.KEEP_CLASSES, context)))
            if classes:
                args += ['--keep-class', ','.join(str(c) for c in classes)]
        return args

    def advancedArgs(self, parameters, context):
        args = []
        if self.parameterDefinition(self.THREADS) is not None:
            threads = self.parameterAsInt(parameters, self.THREADS, context)
            if threads > 0:
                args += ['--threads', str(threads)]
        extra = self.parameterAsString(parameters, self.EXTRA_OPTIONS, context)
        if extra and extra.strip():
            try:
                args += shlex.split(extra)
            except ValueError as e:
                raise QgsProcessingException(tr('Additional tinbuild options: {}').format(e))
        return args

    def runBuild(self, outputArgs, firstOutput, parameters, context, feedback):
        """`tinbuild build INPUTS OUTPUTS ...` with progress, a report beside firstOutput; the report."""
        report = reportPathFor(firstOutput)
        args = (['build'] + self.inputArgs(parameters, context) + outputArgs + self.filterArgs(parameters, context)
                + ['--report', report, '--overwrite', '--progress', 'json']
                + self.advancedArgs(parameters, context))
        exe, version = runner.executable()
        feedback.pushInfo(tr('tinbuild {} at {}').format(runner.versionText(version), exe))
        try:
            runner.run(args, feedback, exe)
        except QgsProcessingException as e:
            # tinbuild names the files it read: a layer written to a temporary GeoPackage for it is named as
            # the user's layer instead.
            message = str(e)
            for path, name in getattr(self, '_layerFiles', {}).items():
                message = message.replace(path, tr('layer {} (written to {} for tinbuild)').format(name, path))
            raise QgsProcessingException(message)
        try:
            with open(report, encoding='utf-8') as f:
                data = json.load(f)
        except (OSError, ValueError) as e:
            raise QgsProcessingException(tr('tinbuild finished but its report {} cannot be read: {}').format(report, e))
        data['_path'] = report
        return data

    def reportResults(self, data):
        tri = data.get('triangulation', {})
        return {self.REPORT: data['_path'], self.POINTS: data.get('points_streamed'),
                self.TRIANGLES: tri.get('triangles'), self.VERTICES: tri.get('vertices')}

    @staticmethod
    def nameOnCompletion(context, path, name, outputName, hint, style=None):
        """A short layer name (and a style) for an output that Processing will load."""
        if path and context.willLoadLayerOnCompletion(path):
            project = context.layerToLoadOnCompletionDetails(path).project
            details = QgsProcessingContext.LayerDetails(name, project, outputName, hint)
            if style is not None:
                details.setPostProcessor(styles.postProcessor(path, style))
            context.addLayerToLoadOnCompletion(path, details)

    @staticmethod
    def loadOnCompletion(context, path, name, outputName, hint, style=None):
        """Load an output the user did not name (a hillshade beside the DEM, HAND in the hydrology folder) under
        its own name: forced, since QGIS's 'prefer the file name' would call it after a fixed file name."""
        if context.project() is not None:
            details = QgsProcessingContext.LayerDetails(name, context.project(), outputName, hint)
            details.forceName = True
            if style is not None:
                details.setPostProcessor(styles.postProcessor(path, style))
            context.addLayerToLoadOnCompletion(path, details)


INPUT_HELP = (
    '<h3>Inputs</h3><p><b>Point cloud files</b>: one or more LAS (1.0-1.4), LAZ, COPC or XYZ files, read as '
    'one survey; or <b>a folder</b>, whose *.las, *.laz and *.xyz files are read (not recursively). '
    '<b>Classes kept</b> defaults to ground (2) and water (9); with none chosen, every class but the noise '
    'classes 7 and 18 is kept. <b>Assign CRS</b> overrides the CRS the files declare (or supplies the one '
    'they lack).</p><p>The work is done by the <code>tinbuild</code> program, found on PATH or set in '
    'Settings > Options > Processing > Providers > tinbuild. Its progress drives the bar; Cancel stops it '
    'and leaves no output. Its run report (<code>--report</code>, JSON) is written beside the first output '
    '(<code>dem.tif</code> gives <code>dem.report.json</code>) and returned as REPORT. Advanced: threads, '
    'and any other tinbuild build options (<code>tinbuild build --help</code>).</p>')


class BuildDem(TinbuildAlgorithm):
    STEP = 'STEP'
    MAX_EDGE = 'MAX_EDGE'
    HILLSHADE = 'HILLSHADE'
    SLOPE = 'SLOPE'
    ASPECT = 'ASPECT'
    TILE_SIZE = 'TILE_SIZE_M'
    COG = 'COG'
    OUTPUT = 'OUTPUT'
    OUTPUT_TILES = 'OUTPUT_TILES'
    OUTPUT_HILLSHADE = 'OUTPUT_HILLSHADE'
    OUTPUT_SLOPE = 'OUTPUT_SLOPE'
    OUTPUT_ASPECT = 'OUTPUT_ASPECT'
    BANDS = ((HILLSHADE, OUTPUT_HILLSHADE, 'hillshade', 'Hillshade'), (SLOPE, OUTPUT_SLOPE, 'slope', 'Slope'),
             (ASPECT, OUTPUT_ASPECT, 'aspect', 'Aspect'))

    _name = 'builddem'
    _displayName = 'Build DEM from point clouds'
    _help = (
        '<p>Builds a DEM from LIDAR point clouds in one streaming pass: the points are triangulated (Delaunay '
        'TIN) and the TIN is interpolated linearly at the pixel centres. Memory follows the survey\'s '
        'width, not its size, so surveys of any size work.</p>'
        '<h3>Parameters</h3><ul>'
        '<li><b>Pixel size</b> (STEP): in metres, also in a survey in feet (default 1 m).</li>'
        '<li><b>Longest triangle edge</b> (MAX_EDGE): pixels under a triangle with a longer edge get no value, '
        'so gaps in the data (water, shadows) stay empty instead of being bridged (metres; default 100; 0: no '
        'limit).</li>'
        '<li><b>Hillshade, slope, aspect</b>: extra rasters on the same grid, beside the DEM '
        '(<code>dem_hillshade.tif</code>; in a tiles folder, <code>hillshade.vrt</code> over its tiles).</li>'
        '<li><b>DEM</b> (OUTPUT): one GeoTIFF. <b>DEM tiles folder</b> (OUTPUT_TILES): instead, GeoTIFF tiles '
        'and their <code>mosaic.vrt</code> in a folder, for large areas; when it is set, the single GeoTIFF is '
        'not written and the result OUTPUT is the mosaic.</li></ul>')

    def initAlgorithm(self, config=None):
        self.addInputParameters()
        self.addConstraintParameters()
        self.addParameter(QgsProcessingParameterNumber(
            self.STEP, tr('Pixel size (metres)'), QgsProcessingParameterNumber.Double, 1.0, minValue=0.001))
        self.addParameter(QgsProcessingParameterNumber(
            self.MAX_EDGE, tr('Longest triangle edge with a value (metres; 0: no limit)'),
            QgsProcessingParameterNumber.Double, 100.0, minValue=0.0))
        self.addParameter(QgsProcessingParameterBoolean(self.HILLSHADE, tr('Also a hillshade raster'), False))
        self.addParameter(QgsProcessingParameterBoolean(self.SLOPE, tr('Also a slope raster (degrees)'), False))
        self.addParameter(QgsProcessingParameterBoolean(
            self.ASPECT, tr('Also an aspect raster (degrees clockwise from north)'), False))
        self.addParameter(advanced(QgsProcessingParameterNumber(
            self.TILE_SIZE, tr('Tile size in a tiles folder (metres; 0: 2048 pixels)'),
            QgsProcessingParameterNumber.Double, 0.0, minValue=0.0)))
        self.addParameter(advanced(QgsProcessingParameterBoolean(
            self.COG, tr('Write Cloud Optimized GeoTIFFs'), False)))
        self.addAdvancedParameters()
        self.addParameter(QgsProcessingParameterRasterDestination(
            self.OUTPUT, tr('DEM (GeoTIFF)'), optional=True, createByDefault=True))
        self.addParameter(QgsProcessingParameterFolderDestination(
            self.OUTPUT_TILES, tr('DEM tiles folder (GeoTIFF tiles and mosaic.vrt), instead of one GeoTIFF'),
            optional=True, createByDefault=False))
        self.addExtraOutputParameters()
        for _, output, _, label in self.BANDS:
            self.addOutput(QgsProcessingOutputRasterLayer(output, tr(label)))
        self.addReportOutputs()

    def addConstraintParameters(self):
        pass

    def addExtraOutputParameters(self):
        pass

    def constraintArgs(self, parameters, context, feedback):
        return []

    def extraOutputArgs(self, parameters, context):
        return [], {}

    def processAlgorithm(self, parameters, context, feedback):
        tiles = self.parameterAsFileOutput(parameters, self.OUTPUT_TILES, context) \
            if parameters.get(self.OUTPUT_TILES) else ''
        if tiles:
            tiles = os.path.abspath(tiles)
            target = tiles
            dem = os.path.join(tiles, 'mosaic.vrt')
        else:
            dem = self.parameterAsOutputLayer(parameters, self.OUTPUT, context)
            if not dem:
                raise QgsProcessingException(tr('Choose where the DEM goes: a GeoTIFF (OUTPUT) or a tiles folder '
                                                '(OUTPUT_TILES).'))
            dem = os.path.abspath(dem)
            target = dem
            self.nameOnCompletion(context, dem, tr('DEM'), self.OUTPUT, QgsProcessingUtils.LayerHint.Raster,
                                  styles.styleDem)
        step = self.parameterAsDouble(parameters, self.STEP, context)
        maxEdge = self.parameterAsDouble(parameters, self.MAX_EDGE, context)
        args = ['--dem', target, '--step', f'{step:g}', '--max-edge', f'{maxEdge:g}']
        for flag, _, option, _ in self.BANDS:
            if self.parameterAsBool(parameters, flag, context):
                args.append('--' + option)
        tileSize = self.parameterAsDouble(parameters, self.TILE_SIZE, context)
        if tiles and tileSize > 0:
            args += ['--tile-size-m', f'{tileSize:g}']
        if self.parameterAsBool(parameters, self.COG, context):
            args.append('--cog')
        args += self.constraintArgs(parameters, context, feedback)
        extraArgs, extraResults = self.extraOutputArgs(parameters, context)
        args += extraArgs

        data = self.runBuild(args, target, parameters, context, feedback)

        results = self.reportResults(data)
        results.update({self.OUTPUT: dem, self.OUTPUT_TILES: tiles or None})
        results.update(extraResults)
        files = [os.path.abspath(f) for f in data.get('dem', {}).get('files', [])]
        load = bool(tiles) or context.willLoadLayerOnCompletion(dem)
        if tiles:
            self.loadOnCompletion(context, dem, tr('DEM'), self.OUTPUT, QgsProcessingUtils.LayerHint.Raster,
                                  styles.styleDem)
        for flag, output, option, label in self.BANDS:
            path = next((f for f in files if os.path.basename(f) in (option + '.vrt',)
                         or f.endswith('_' + option + os.path.splitext(f)[1])), None)
            results[output] = path if self.parameterAsBool(parameters, flag, context) else None
            if results[output] and load:
                self.loadOnCompletion(context, path, tr(label), output, QgsProcessingUtils.LayerHint.Raster,
                                      styles.styleHillshade if flag == self.HILLSHADE else None)
        return results


class HydroFlatten(BuildDem):
    BREAKLINES = 'BREAKLINES'
    WATER = 'WATER'
    FLOW = 'FLOW'
    OUTPUT_TIN = 'OUTPUT_TIN'

    _name = 'hydroflatten'
    _displayName = 'Build hydro-flattened DEM (breaklines, water, rivers)'
    _help = (
        '<p>Builds a DEM like <i>Build DEM</i>, with constraints taken from vector layers of the project:</p><ul>'
        '<li><b>Breaklines</b> (lines, or polygons whose rings are used; with Z): hard edges of the TIN at '
        'the line\'s height, such as road crests, kerbs and dam tops.</li>'
        '<li><b>Water polygons</b>: lidar points inside are left out; a lake is flat at or below its shore, a '
        'river (a polygon crossed by a centreline) is level across.</li>'
        '<li><b>River centrelines</b> (lines digitised downstream): the rivers they cross never rise '
        'downstream.</li></ul><p>At least breaklines or water polygons are needed. A layer that is a whole '
        'single-layer file is read by tinbuild as it is; any other layer (memory, filtered, database, one '
        'layer of a multi-layer GeoPackage) is written to a temporary GeoPackage first. '
        '<b>TIN</b> (OUTPUT_TIN, optional): the hydro-flattened TIN as a GeoPackage layer.</p>'
        + BuildDem._help.split('<h3>Parameters</h3>', 1)[1])

    def addConstraintParameters(self):
        self.addParameter(QgsProcessingParameterMultipleLayers(
            self.BREAKLINES, tr('Breaklines (lines or polygons with Z)'), QgsProcessing.TypeVectorAnyGeometry,
            optional=True))
        self.addParameter(QgsProcessingParameterMultipleLayers(
            self.WATER, tr('Water polygons (lakes and rivers)'), QgsProcessing.TypeVectorPolygon, optional=True))
        self.addParameter(QgsProcessingParameterMultipleLayers(
            self.FLOW, tr('River centrelines (digitised downstream)'), QgsProcessing.TypeVectorLine,
            optional=True))

    def addExtraOutputParameters(self):
        self.addParameter(QgsProcessingParameterVectorDestination(
            self.OUTPUT_TIN, tr('Hydro-flattened TIN (GeoPackage)'), QgsProcessing.TypeVectorPolygon,
            optional=True, createByDefault=False))

    def checkParameterValues(self, parameters, context):
        ok, message = super().checkParameterValues(parameters, context)
        if not ok:
            return ok, message
        if not (self.parameterAsLayerList(parameters, self.BREAKLINES, context)
                or self.parameterAsLayerList(parameters, self.WATER, context)):
            return False, tr('Choose breaklines or water polygons (or both): without them use Build DEM.')
        return True, ''

    def constraintArgs(self, parameters, context, feedback):
        args = []
        scratch = None
        self._layerFiles = {}
        for name, option in ((self.BREAKLINES, '--breaklines'), (self.WATER, '--water'), (self.FLOW, '--flow')):
            for layer in self.parameterAsLayerList(parameters, name, context):
                # An empty layer is the user's mistake to hear about by its name, before any work (tinbuild
                # would name the temporary file it was written to).
                if isinstance(layer, QgsVectorLayer) and layer.isValid() and layer.featureCount() == 0:
                    raise QgsProcessingException(tr('{}: the layer {} has no features ({})').format(
                        option, layer.name(), layer.source()))
                if scratch is None:
                    scratch = tempfile.mkdtemp(prefix='tinbuild-', dir=QgsProcessingUtils.tempFolder())
                path = layerAsFile(layer, context, feedback, scratch)
                if os.path.dirname(path) == scratch:
                    self._layerFiles[path] = layer.name()
                args += [option, path]
        return args

    def extraOutputArgs(self, parameters, context):
        tin = self.parameterAsOutputLayer(parameters, self.OUTPUT_TIN, context) \
            if parameters.get(self.OUTPUT_TIN) else ''
        if not tin:
            return [], {self.OUTPUT_TIN: None}
        tin = checkGpkg(tin)
        self.nameOnCompletion(context, tin, tr('TIN'), self.OUTPUT_TIN, QgsProcessingUtils.LayerHint.Vector)
        return ['--gpkg', tin], {self.OUTPUT_TIN: tin}


def checkGpkg(path):
    path = os.path.abspath(path)
    if not path.lower().endswith('.gpkg'):
        raise QgsProcessingException(tr('{}: tinbuild writes this output as a GeoPackage (.gpkg)').format(path))
    return path


def layerAsFile(layer, context, feedback, scratch):
    """A file tinbuild can read holding exactly this layer's features (see the module's notes)."""
    if not isinstance(layer, QgsVectorLayer) or not layer.isValid():
        raise QgsProcessingException(tr('{} is not a valid vector layer').format(layer.name() if layer else layer))
    if layer.providerType() == 'ogr' and not layer.subsetString():
        parts = QgsProviderRegistry.instance().decodeUri('ogr', layer.source())
        path = parts.get('path') or ''
        if os.path.isfile(path) and len(layer.dataProvider().subLayers()) <= 1:
            return path
    out = os.path.join(scratch, f'{len(os.listdir(scratch)):02d}_' +
                       ''.join(c if c.isalnum() else '_' for c in layer.name())[:40] + '.gpkg')
    options = QgsVectorFileWriter.SaveVectorOptions()
    options.driverName = 'GPKG'
    options.layerName = 'constraints'
    options.fileEncoding = 'UTF-8'
    result = QgsVectorFileWriter.writeAsVectorFormatV3(layer, out, context.transformContext(), options)
    if result[0] != QgsVectorFileWriter.NoError:
        raise QgsProcessingException(tr('Cannot write layer {} to {} for tinbuild: {}').format(
            layer.name(), out, result[1]))
    feedback.pushInfo(tr('Layer {} written to {} for tinbuild').format(layer.name(), out))
    return out


class BuildTin(TinbuildAlgorithm):
    OUTPUT = 'OUTPUT'
    OUTPUT_MESH = 'OUTPUT_MESH'

    _name = 'buildtin'
    _displayName = 'Build TIN from point clouds'
    _help = (
        '<p>Triangulates LIDAR point clouds (an exact Delaunay TIN, streamed: memory follows the survey\'s '
        'width, not its size) and writes the TIN as</p><ul>'
        '<li><b>TIN</b> (OUTPUT): a GeoPackage with a layer <code>tin</code> of 3D triangles (POLYGON Z) and its '
        'spatial index, loaded as a vector layer;</li>'
        '<li><b>TIN mesh</b> (OUTPUT_MESH, optional): a UGRID NetCDF mesh (.nc) with the CRS and the heights on '
        'its vertices, loaded as a mesh layer.</li></ul><p>Either or both.</p>')

    def initAlgorithm(self, config=None):
        self.addInputParameters()
        self.addAdvancedParameters()
        self.addParameter(QgsProcessingParameterVectorDestination(
            self.OUTPUT, tr('TIN (GeoPackage layer of triangles)'), QgsProcessing.TypeVectorPolygon,
            optional=True, createByDefault=True))
        self.addParameter(QgsProcessingParameterFileDestination(
            self.OUTPUT_MESH, tr('TIN mesh (UGRID NetCDF)'), tr('UGRID NetCDF mesh (*.nc)'),
            optional=True, createByDefault=False))
        self.addReportOutputs()

    def processAlgorithm(self, parameters, context, feedback):
        gpkg = self.parameterAsOutputLayer(parameters, self.OUTPUT, context) if parameters.get(self.OUTPUT) else ''
        mesh = self.parameterAsFileOutput(parameters, self.OUTPUT_MESH, context) \
            if parameters.get(self.OUTPUT_MESH) else ''
        if not gpkg and not mesh:
            raise QgsProcessingException(tr('Choose an output: a GeoPackage (OUTPUT), a UGRID mesh (OUTPUT_MESH) '
                                            'or both.'))
        args = []
        if gpkg:
            gpkg = checkGpkg(gpkg)
            self.nameOnCompletion(context, gpkg, tr('TIN'), self.OUTPUT, QgsProcessingUtils.LayerHint.Vector)
            args += ['--gpkg', gpkg]
        if mesh:
            mesh = os.path.abspath(mesh)
            if not mesh.lower().endswith('.nc'):
                raise QgsProcessingException(tr('{}: the TIN mesh is a UGRID NetCDF file (.nc)').format(mesh))
            args += ['--mesh', mesh]
        data = self.runBuild(args, gpkg or mesh, parameters, context, feedback)
        if mesh:
            self.loadOnCompletion(context, mesh, tr('TIN mesh'), self.OUTPUT_MESH, QgsProcessingUtils.LayerHint.Mesh)
        results = self.reportResults(data)
        results.update({self.OUTPUT: gpkg or None, self.OUTPUT_MESH: mesh or None})
        return results


class Contours(TinbuildAlgorithm):
    INTERVAL = 'INTERVAL'
    BASE = 'BASE'
    INDEX_EVERY = 'INDEX_EVERY'
    SIMPLIFY = 'SIMPLIFY'
    MIN_LENGTH = 'MIN_LENGTH'
    OUTPUT = 'OUTPUT'
    LINES = 'LINES'

    _name = 'contours'
    _displayName = 'Contour lines from point clouds'
    _help = (
        '<p>Contour lines of the TIN of LIDAR point clouds, traced on the triangles themselves (exact, no DEM '
        'in between), as 3D lines (LINESTRING Z) in a GeoPackage layer <code>contours</code> with the fields '
        '<code>elev</code> and <code>index</code>.</p><ul>'
        '<li><b>Interval</b>: the spacing of the levels, in the survey\'s height units (default 1).</li>'
        '<li><b>Index contour every</b>: every N-th level is an index contour (<code>index</code> = 1; default '
        '5; 0: none).</li>'
        '<li><b>Simplify</b>: drops vertices within this distance (CRS units) of the simplified line, never '
        'letting lines cross or loops change what they enclose (default 0: exact).</li>'
        '<li>Advanced: the base level (levels are base + k x interval) and the shortest closed loop kept.</li>'
        '</ul>')

    def initAlgorithm(self, config=None):
        self.addInputParameters()
        self.addParameter(QgsProcessingParameterNumber(
            self.INTERVAL, tr('Interval (height units)'), QgsProcessingParameterNumber.Double, 1.0,
            minValue=0.000001))
        self.addParameter(QgsProcessingParameterNumber(
            self.INDEX_EVERY, tr('Index contour every N levels (0: none)'), QgsProcessingParameterNumber.Integer,
            5, minValue=0))
        self.addParameter(QgsProcessingParameterNumber(
            self.SIMPLIFY, tr('Simplify tolerance (CRS units; 0: exact)'), QgsProcessingParameterNumber.Double,
            0.0, minValue=0.0))
        self.addParameter(advanced(QgsProcessingParameterNumber(
            self.BASE, tr('Base level'), QgsProcessingParameterNumber.Double, 0.0)))
        self.addParameter(advanced(QgsProcessingParameterNumber(
            self.MIN_LENGTH, tr('Drop closed loops shorter than (CRS units)'), QgsProcessingParameterNumber.Double,
            0.0, minValue=0.0)))
        self.addAdvancedParameters()
        self.addParameter(QgsProcessingParameterVectorDestination(
            self.OUTPUT, tr('Contours (GeoPackage)'), QgsProcessing.TypeVectorLine))
        self.addReportOutputs()
        self.addOutput(QgsProcessingOutputNumber(self.LINES, tr('Contour lines')))

    def processAlgorithm(self, parameters, context, feedback):
        out = checkGpkg(self.parameterAsOutputLayer(parameters, self.OUTPUT, context))
        self.nameOnCompletion(context, out, tr('Contours'), self.OUTPUT, QgsProcessingUtils.LayerHint.Vector)
        args = ['--contours', out,
                '--interval', f'{self.parameterAsDouble(parameters, self.INTERVAL, context):g}',
                '--index-every', str(self.parameterAsInt(parameters, self.INDEX_EVERY, context))]
        for name, option in ((self.SIMPLIFY, '--simplify'), (self.BASE, '--base'), (self.MIN_LENGTH, '--min-length')):
            value = self.parameterAsDouble(parameters, name, context)
            if value:
                args += [option, f'{value:.12g}']
        data = self.runBuild(args, out, parameters, context, feedback)
        results = self.reportResults(data)
        results.update({self.OUTPUT: out, self.LINES: data.get('contours', {}).get('lines')})
        return results


class Info(TinbuildAlgorithm):
    OUTPUT_HTML_FILE = 'OUTPUT_HTML_FILE'
    OUTPUT_JSON = 'OUTPUT_JSON'
    CRS_AUTHID = 'CRS_AUTHID'
    CRS_NAME = 'CRS_NAME'

    _name = 'info'
    _displayName = 'Survey summary (info)'
    _group = 'Survey'
    _groupId = 'survey'
    _help = (
        '<p>What to know about a survey before processing it, as an HTML report in the results viewer: '
        'format and version, point format and compression, points by class and by return, withheld points and '
        'xy duplicates, bounds, the CRS (name, EPSG code, units, where it came from, doubts), density and '
        'point spacing, and the stream\'s coherence (how many points a streaming build holds at most). '
        'Several files are read as one survey. Optionally the same facts as JSON (<code>tinbuild info '
        '--json</code>). The point count, the CRS and its name are also returned as results.</p>')

    def initAlgorithm(self, config=None):
        self.addInputParameters(classes=False)
        self.addAdvancedParameters(threads=False)
        self.addParameter(QgsProcessingParameterFileDestination(
            self.OUTPUT_HTML_FILE, tr('Survey summary'), tr('HTML files (*.html *.htm)')))
        self.addParameter(QgsProcessingParameterFileDestination(
            self.OUTPUT_JSON, tr('Survey summary as JSON'), tr('JSON files (*.json)'), optional=True,
            createByDefault=False))
        self.addOutput(QgsProcessingOutputNumber(self.POINTS, tr('Points')))
        self.addOutput(QgsProcessingOutputString(self.CRS_AUTHID, tr('CRS (EPSG code, or empty)')))
        self.addOutput(QgsProcessingOutputString(self.CRS_NAME, tr('CRS name')))

    def processAlgorithm(self, parameters, context, feedback):
        html = os.path.abspath(self.parameterAsFileOutput(parameters, self.OUTPUT_HTML_FILE, context))
        jsonPath = self.parameterAsFileOutput(parameters, self.OUTPUT_JSON, context) \
            if parameters.get(self.OUTPUT_JSON) else ''
        exe, version = runner.executable()
        args = ['info'] + self.inputArgs(parameters, context) + ['--json'] + self.advancedArgs(parameters, context)
        text = runner.run(args, feedback, exe)
        try:
            data = json.loads(text)
        except ValueError as e:
            raise QgsProcessingException(tr('tinbuild info did not print JSON ({}): {}').format(e, text[:300]))
        os.makedirs(os.path.dirname(html) or '.', exist_ok=True)
        with open(html, 'w', encoding='utf-8') as f:
            f.write(infoHtml(data, runner.versionText(version)))
        if jsonPath:
            jsonPath = os.path.abspath(jsonPath)
            os.makedirs(os.path.dirname(jsonPath) or '.', exist_ok=True)
            with open(jsonPath, 'w', encoding='utf-8') as f:
                json.dump(data, f, indent=2)
        crs = data.get('crs') or {}
        authid = f"EPSG:{crs['epsg']}" if crs.get('epsg') else ''
        feedback.pushInfo(tr('{:,} points; CRS {}').format(data.get('points', 0), crs.get('name') or tr('none')))
        return {self.OUTPUT_HTML_FILE: html, self.OUTPUT_JSON: jsonPath or None, self.POINTS: data.get('points'),
                self.CRS_AUTHID: authid, self.CRS_NAME: crs.get('name') or ''}


class Hydrology(TinbuildAlgorithm):
    DEM = 'DEM'
    STREAM_AREA = 'STREAM_AREA'
    STAGE = 'STAGE'
    FLOW = 'FLOW'
    OUTPUT_FOLDER = 'OUTPUT_FOLDER'
    HAND = 'HAND'
    STREAMS = 'STREAMS'
    DEPTH = 'DEPTH'
    FLOOD = 'FLOOD'
    LINKS = 'LINKS'
    FLOODED_CELLS = 'FLOODED_CELLS'

    _name = 'hydrology'
    _displayName = 'Floodplain hydrology (fill, streams, HAND, flood depth)'
    _group = 'Hydrology'
    _groupId = 'hydrology'

    def checkParameterValues(self, parameters, context):
        # (a DEM, not point clouds: the point-cloud algorithms' check of INPUT does not apply)
        return QgsProcessingAlgorithm.checkParameterValues(self, parameters, context)

    def tags(self):
        return ['hydrology', 'hand', 'flood', 'fill', 'flow direction', 'd8', 'streams', 'catchments',
                'upstream area', 'flow accumulation', 'dem', 'tinbuild']

    def shortHelpString(self):
        return tr(
            '<p>Floodplain hydrology of a DEM, tile by tile in bounded memory (any size of DEM): depressions '
            'filled to their spill level, D8 flow directions (flats drained towards lower terrain), upstream '
            'area, streams where the upstream area reaches the <b>stream area</b>, catchments, and '
            '<b>HAND</b> (height above the nearest drainage: how far each cell lies above the stream cell its '
            'water reaches). With a <b>flood stage</b> H, the water depth where HAND is at most H and the '
            'flood\'s extent as polygons.</p><ul>'
            '<li><b>DEM</b>: any raster in a projected CRS (a geographic one is refused: reproject it first); a '
            'tinbuild DEM tiles folder\'s <code>mosaic.vrt</code> works as it is.</li>'
            '<li><b>Stream centrelines</b> (optional, digitised downstream): breached into the DEM so the '
            'streams pass under roads (road embankments otherwise dam every stream).</li>'
            '<li><b>Output folder</b>: every raster as GeoTIFF tiles with its <code>NAME.vrt</code> (filled, '
            'flowdir, accum, streams, catchments, hand, depth) and <code>streams.gpkg</code>, '
            '<code>flood.gpkg</code>; HAND, the stream lines, the depth and the flood are loaded.</li></ul>'
            '<p>The run report (JSON) is written beside the folder (<code>DIR.report.json</code>).</p>')

    def initAlgorithm(self, config=None):
        self.addParameter(QgsProcessingParameterRasterLayer(self.DEM, tr('DEM')))
        self.addParameter(QgsProcessingParameterNumber(
            self.STREAM_AREA, tr('Stream area: upstream area that makes a stream (hectares)'),
            QgsProcessingParameterNumber.Double, 100.0, minValue=0.0001))
        self.addParameter(QgsProcessingParameterNumber(
            self.STAGE, tr('Flood stage above the drainage (height units; empty: no flood)'),
            QgsProcessingParameterNumber.Double, None, optional=True, minValue=0.0))
        self.addParameter(QgsProcessingParameterMultipleLayers(
            self.FLOW, tr('Stream centrelines to breach through embankments (digitised downstream)'),
            QgsProcessing.TypeVectorLine, optional=True))
        self.addAdvancedParameters()
        self.addParameter(QgsProcessingParameterFolderDestination(self.OUTPUT_FOLDER, tr('Output folder')))
        self.addOutput(QgsProcessingOutputRasterLayer(self.HAND, tr('HAND')))
        self.addOutput(QgsProcessingOutputVectorLayer(self.STREAMS, tr('Streams'), QgsProcessing.TypeVectorLine))
        self.addOutput(QgsProcessingOutputRasterLayer(self.DEPTH, tr('Flood depth')))
        self.addOutput(QgsProcessingOutputVectorLayer(self.FLOOD, tr('Flood extent'), QgsProcessing.TypeVectorPolygon))
        self.addOutput(QgsProcessingOutputFile(self.REPORT, tr('Run report (JSON)')))
        self.addOutput(QgsProcessingOutputNumber(self.LINKS, tr('Stream links')))
        self.addOutput(QgsProcessingOutputNumber(self.FLOODED_CELLS, tr('Flooded cells')))

    def processAlgorithm(self, parameters, context, feedback):
        layer = self.parameterAsRasterLayer(parameters, self.DEM, context)
        if layer is None or not layer.isValid():
            raise QgsProcessingException(tr('Choose a DEM raster layer'))
        dem = layer.source()
        if layer.providerType() != 'gdal' or not (os.path.exists(dem) or dem.lower().startswith('/vsi')):
            raise QgsProcessingException(tr('The DEM {} is not a raster file tinbuild can read ({})').format(
                layer.name(), dem))
        out = os.path.abspath(self.parameterAsString(parameters, self.OUTPUT_FOLDER, context))
        report = reportPathFor(out)
        area = self.parameterAsDouble(parameters, self.STREAM_AREA, context)
        args = ['hydrology', dem, '-o', out, '--stream-area', f'{area:.12g}ha', '--overwrite',
                '--report', report, '--progress', 'json']
        stage = parameters.get(self.STAGE)
        staged = stage is not None and stage != ''
        if staged:
            args += ['--stage', f'{self.parameterAsDouble(parameters, self.STAGE, context):.12g}']
        flows = self.parameterAsLayerList(parameters, self.FLOW, context)
        if flows:
            scratch = tempfile.mkdtemp(prefix='tinbuild-', dir=QgsProcessingUtils.tempFolder())
            for flow in flows:
                args += ['--flow', layerAsFile(flow, context, feedback, scratch)]
        args += self.advancedArgs(parameters, context)
        exe, version = runner.executable()
        feedback.pushInfo(tr('tinbuild {} at {}').format(runner.versionText(version), exe))
        runner.run(args, feedback, exe)
        try:
            with open(report, encoding='utf-8') as f:
                data = json.load(f)
        except (OSError, ValueError) as e:
            raise QgsProcessingException(tr('tinbuild finished but its report {} cannot be read: {}').format(report, e))
        hand = os.path.join(out, 'hand.vrt')
        streams = os.path.join(out, 'streams.gpkg') + '|layername=streams'
        self.loadOnCompletion(context, hand, tr('HAND'), self.HAND, QgsProcessingUtils.LayerHint.Raster,
                                           styles.styleHand)
        self.loadOnCompletion(context, streams, tr('Streams'), self.STREAMS,
                                           QgsProcessingUtils.LayerHint.Vector, styles.styleStreams)
        results = {self.HAND: hand, self.STREAMS: streams, self.DEPTH: None, self.FLOOD: None, self.REPORT: report,
                   self.LINKS: data.get('streams', {}).get('links'),
                   self.FLOODED_CELLS: data.get('drainage', {}).get('flooded_cells')}
        if staged:
            depth = os.path.join(out, 'depth.vrt')
            flood = os.path.join(out, 'flood.gpkg') + '|layername=flood'
            self.loadOnCompletion(context, depth, tr('Flood depth'), self.DEPTH,
                                               QgsProcessingUtils.LayerHint.Raster, styles.styleDepth)
            self.loadOnCompletion(context, flood, tr('Flood extent'), self.FLOOD,
                                               QgsProcessingUtils.LayerHint.Vector, styles.styleFlood)
            results.update({self.DEPTH: depth, self.FLOOD: flood})
        return results


ALGORITHMS = [BuildDem, HydroFlatten, BuildTin, Contours, Info, Hydrology]
