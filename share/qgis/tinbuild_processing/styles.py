"""How the provider's rasters look when Processing loads them: a DEM coloured by height, a hillshade
multiplied over it, a slope in greys.

Processing loads a result layer and then calls the post-processor of its LayerDetails.  QGIS does not
keep the Python object alive by itself, so every post-processor made is also kept in _KEEP, keyed by the
output's path (a new run on the same path replaces it).
"""
from qgis.PyQt.QtGui import QColor, QPainter
from qgis.core import (QgsColorRampShader, QgsGradientColorRamp, QgsGradientStop,
                       QgsProcessingLayerPostProcessorInterface, QgsRasterBandStats, QgsRasterShader,
                       QgsSingleBandPseudoColorRenderer)

_KEEP = {}

# Low to high: valley green, meadow, dry grass, rock brown, near-white summits.
TERRAIN_STOPS = [(0.0, '#3a7d44'), (0.25, '#8fbf5a'), (0.5, '#e6d98c'), (0.75, '#b5835a'), (1.0, '#f4f1ec')]


def terrainRamp():
    first, last = TERRAIN_STOPS[0][1], TERRAIN_STOPS[-1][1]
    stops = [QgsGradientStop(p, QColor(c)) for p, c in TERRAIN_STOPS[1:-1]]
    return QgsGradientColorRamp(QColor(first), QColor(last), False, stops)


def styleDem(layer):
    """Single-band pseudocolour over the DEM's 2..98 % heights, interpolated."""
    provider = layer.dataProvider()
    stats = provider.bandStatistics(1, QgsRasterBandStats.Min | QgsRasterBandStats.Max)
    lo, hi = stats.minimumValue, stats.maximumValue
    if not hi > lo:
        return
    shader = QgsColorRampShader(lo, hi)
    shader.setColorRampType(QgsColorRampShader.Interpolated)
    shader.setSourceColorRamp(terrainRamp())
    shader.classifyColorRamp(5, 1, layer.extent(), provider)
    rasterShader = QgsRasterShader(lo, hi)
    rasterShader.setRasterShaderFunction(shader)
    renderer = QgsSingleBandPseudoColorRenderer(provider, 1, rasterShader)
    renderer.setClassificationMin(lo)
    renderer.setClassificationMax(hi)
    layer.setRenderer(renderer)
    layer.triggerRepaint()


def styleHillshade(layer):
    """Multiplied over the layers below it at 60 %, so the DEM's colours show through its shading."""
    layer.setBlendMode(QPainter.CompositionMode_Multiply)
    layer.setOpacity(0.6)   # (QgsMapLayer.setOpacity: QGIS 3.18 and newer)
    layer.triggerRepaint()


def _pseudocolour(layer, stops, lo, hi):
    """An interpolated ramp of (value, colour) stops between lo and hi on band 1."""
    shader = QgsColorRampShader(lo, hi)
    shader.setColorRampType(QgsColorRampShader.Interpolated)
    shader.setColorRampItemList([QgsColorRampShader.ColorRampItem(v, QColor(c), f'{v:g}') for v, c in stops])
    rasterShader = QgsRasterShader(lo, hi)
    rasterShader.setRasterShaderFunction(shader)
    renderer = QgsSingleBandPseudoColorRenderer(layer.dataProvider(), 1, rasterShader)
    renderer.setClassificationMin(lo)
    renderer.setClassificationMax(hi)
    layer.setRenderer(renderer)
    layer.triggerRepaint()


def styleHand(layer):
    """HAND: deep green at the drainage through yellow (5) to light brown (20 and above)."""
    _pseudocolour(layer, [(0, '#1f7a46'), (1, '#5fae5a'), (2.5, '#b8d86b'), (5, '#f1e08a'), (10, '#dcb27c'),
                          (20, '#c9b8a6')], 0, 20)


def styleDepth(layer):
    """Flood depth: light to dark blue, 0 transparent."""
    _pseudocolour(layer, [(0, '#00000000'), (0.01, '#c6dbef'), (0.5, '#6baed6'), (1.5, '#2171b5'),
                          (3, '#08306b')], 0, 3)
    layer.setOpacity(0.8)


def styleStreams(layer):
    """Stream lines in blue, wider with the Strahler order."""
    from qgis.core import QgsProperty, QgsSymbolLayer
    symbol = layer.renderer().symbol()
    symbol.setColor(QColor('#1f4e9c'))
    symbol.symbolLayer(0).setDataDefinedProperty(
        QgsSymbolLayer.PropertyStrokeWidth, QgsProperty.fromExpression('0.2 + 0.35 * "strahler"'))
    layer.triggerRepaint()


def styleFlood(layer):
    """The flood's extent: a light blue outline, no fill (the depth shows the water)."""
    symbol = layer.renderer().symbol()
    symbol.setColor(QColor(0, 0, 0, 0))
    symbol.symbolLayer(0).setStrokeColor(QColor('#3b7dd8'))
    layer.triggerRepaint()


class Styler(QgsProcessingLayerPostProcessorInterface):
    def __init__(self, style):
        super().__init__()
        self.style = style

    def postProcessLayer(self, layer, context, feedback):
        try:
            self.style(layer)
        except Exception as e:  # a style is a nicety: never fail the run over it
            feedback.pushInfo(f'Could not style {layer.name()}: {e}')


def postProcessor(path, style):
    styler = Styler(style)
    _KEEP[path] = styler
    return styler
