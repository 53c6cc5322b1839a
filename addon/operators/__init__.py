"""Operators, one per file; ``classes`` is registered in this order."""

from .add_spot_click import PLATOLIDAR_OT_add_spot_click
from .add_spot_cursor import PLATOLIDAR_OT_add_spot_cursor
from .advise_spots import PLATOLIDAR_OT_advise_spots
from .cancel_job import PLATOLIDAR_OT_cancel_job
from .check_environment import PLATOLIDAR_OT_check_environment
from .evaluate import PLATOLIDAR_OT_evaluate, PLATOLIDAR_OT_open_summary
from .export_config import PLATOLIDAR_OT_export_config
from .generate_spots import PLATOLIDAR_OT_generate_spots
from .import_reconstruction import PLATOLIDAR_OT_import_reconstruction
from .import_visible_depth import PLATOLIDAR_OT_import_visible_depth
from .load_config import PLATOLIDAR_OT_load_config
from .reconstruct import PLATOLIDAR_OT_reconstruct
from .remove_spot import PLATOLIDAR_OT_remove_spot
from .setup_environment import PLATOLIDAR_OT_setup_environment
from .simulate import PLATOLIDAR_OT_simulate

classes = (
    PLATOLIDAR_OT_add_spot_cursor,
    PLATOLIDAR_OT_add_spot_click,
    PLATOLIDAR_OT_remove_spot,
    PLATOLIDAR_OT_generate_spots,
    PLATOLIDAR_OT_advise_spots,
    PLATOLIDAR_OT_export_config,
    PLATOLIDAR_OT_load_config,
    PLATOLIDAR_OT_simulate,
    PLATOLIDAR_OT_reconstruct,
    PLATOLIDAR_OT_evaluate,
    PLATOLIDAR_OT_open_summary,
    PLATOLIDAR_OT_cancel_job,
    PLATOLIDAR_OT_check_environment,
    PLATOLIDAR_OT_setup_environment,
    PLATOLIDAR_OT_import_reconstruction,
    PLATOLIDAR_OT_import_visible_depth,
)
