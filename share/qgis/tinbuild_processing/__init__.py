"""tinbuild's QGIS plugin: a Processing provider (id `tinbuild`) that runs the tinbuild executable.

Install by copying or symlinking this folder into the QGIS profile's `python/plugins/` folder, or with
Plugins > Manage and Install Plugins > Install from ZIP on the zip that share/qgis/make-zip.sh builds.
"""


def classFactory(iface):  # QGIS's entry point; iface is None when QGIS runs headless
    from .plugin import TinbuildPlugin
    return TinbuildPlugin(iface)
