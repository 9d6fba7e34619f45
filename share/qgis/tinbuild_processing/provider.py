"""The Processing provider `tinbuild`: its algorithms, its icon and its one setting.

The setting (`TINBUILD_EXECUTABLE`, shown under Settings > Options > Processing > Providers > tinbuild)
is the path of the tinbuild executable; empty means `tinbuild` on PATH.  It lives in Processing's
ProcessingConfig, which also works headless (qgis_process, a standalone script), where there is no
options dialog: a script sets it with ProcessingConfig.setSettingValue().  Outputs are files only
(tinbuild writes them itself), so the provider offers GeoTIFF for rasters and GeoPackage for vectors and
no memory layers: QGIS then turns a "temporary layer" choice into a temporary file.
"""
import configparser
import os

from qgis.PyQt.QtGui import QIcon
from qgis.core import QgsProcessingProvider

from . import runner
from .algorithms import ALGORITHMS, ICON

PLUGIN_DIR = os.path.dirname(__file__)


def pluginVersion():
    cp = configparser.ConfigParser()
    cp.read(os.path.join(PLUGIN_DIR, 'metadata.txt'), encoding='utf-8')
    return cp.get('general', 'version', fallback='')


class TinbuildProvider(QgsProcessingProvider):

    def id(self):
        return 'tinbuild'

    def name(self):
        return 'tinbuild'

    def longName(self):
        return 'tinbuild: streaming LIDAR to TIN and DEM'

    def icon(self):
        return QIcon(ICON)

    def svgIconPath(self):
        return ICON

    def versionInfo(self):
        return pluginVersion()

    def load(self):
        try:
            from processing.core.ProcessingConfig import ProcessingConfig, Setting
        except ImportError:  # no Processing plugin: the executable is found on PATH only
            ProcessingConfig = None
        if ProcessingConfig is not None:
            ProcessingConfig.setGroupIcon(self.name(), self.icon())
            ProcessingConfig.addSetting(Setting(
                self.name(), runner.SETTING_EXECUTABLE,
                self.tr('tinbuild executable (empty: tinbuild on PATH; needs {} or newer)').format(
                    runner.versionText(runner.MIN_VERSION)),
                '', valuetype=Setting.FILE))
            ProcessingConfig.readSettings()
        self.refreshAlgorithms()
        return True

    def unload(self):
        try:
            from processing.core.ProcessingConfig import ProcessingConfig
            if runner.SETTING_EXECUTABLE in ProcessingConfig.settings:
                ProcessingConfig.removeSetting(runner.SETTING_EXECUTABLE)
        except ImportError:
            pass

    def loadAlgorithms(self):
        for cls in ALGORITHMS:
            self.addAlgorithm(cls())

    def supportedOutputRasterLayerExtensions(self):
        return ['tif']

    def supportedOutputVectorLayerExtensions(self):
        return ['gpkg']

    def defaultVectorFileExtension(self, hasGeometry=True):
        return 'gpkg'

    def defaultRasterFileExtension(self):
        return 'tif'

    def supportsNonFileBasedOutput(self):
        return False
