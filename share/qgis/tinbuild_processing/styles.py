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
