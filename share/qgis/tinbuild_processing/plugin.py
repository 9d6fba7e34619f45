"""The plugin object QGIS creates through classFactory().

QGIS desktop calls initGui(); qgis_process and other headless hosts call only initProcessing() (with
`hasProcessingProvider=yes` in metadata.txt), and there classFactory gets no iface.  Both register the
same provider, once.
"""
from qgis.core import QgsApplication

from .provider import TinbuildProvider


class TinbuildPlugin:

    def __init__(self, iface=None):
        self.iface = iface
        self.provider = None

    def initProcessing(self):
        if self.provider is None:
            self.provider = TinbuildProvider()
            QgsApplication.processingRegistry().addProvider(self.provider)

    def initGui(self):
        self.initProcessing()

    def unload(self):
        if self.provider is not None:
            QgsApplication.processingRegistry().removeProvider(self.provider)
            self.provider = None
