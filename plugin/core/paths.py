"""Where the plugin's files are: its root folder (the repository root, or the folder QGIS
installed it to) and the resources shipped with it (styles, models, templates, icons)."""
from pathlib import Path

PLUGIN_ROOT = Path(__file__).resolve().parents[2]
RESOURCES = PLUGIN_ROOT / "resources"
