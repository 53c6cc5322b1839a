"""The fast mode's settings (`fit --set fast.KEY=...`): one field per stage of docs/reconstruction.md's "The fast
default, stage by stage", each with why and what was measured. Checked in config.FitConfig.__post_init__ (the
one place that names a bad value); split from config.py for its size."""

from __future__ import annotations

from dataclasses import dataclass


_S15 = "removed in session 15 (measured no better on any scene: docs/reconstruction.md"


@dataclass
class FastConfig:
    """Explicit multi-resolution density grid."""

    #: keys older versions wrote (a saved fit.json / --config) -> what replaced them (settings.from_dict says so)
    REMOVED_SETTINGS = {"tv_weight": "replaced by fast.normal_weight (session 8: the total-variation term did nothing)",
                        "footprint_voxels": "removed in session 8 (ray-footprint carving kept no legs; docs/reconstruction.md)",
                        "footprint_views": "removed in session 8 (ray-footprint carving kept no legs; docs/reconstruction.md)",
                        "explain_pick": f"{_S15}, 'Blockers chosen together': each segment keeps its own blocker)",
                        "explain_cover_lit_power": f"{_S15}, 'Blockers chosen together')",
                        "explain_min_plane_neighbours": f"{_S15}, 'restored specks carved again')",
                        "mesh_lone_inset_voxels": f"{_S15}, 'Thin sheets inside their voxel')",
                        "mesh_hull_taubin_iterations": f"{_S15}, 'organic-occluded's blob')",
                        "mesh_hull_flat_centre_voxels": "removed in session 15 (superseded by the default "
                                                        "fast.mesh_hull_flat_approach, which moves those faces by the "
                                                        "light's gap: docs/reconstruction.md)"}

    coarse_resolution: int = 64       # voxels along the longest bbox side, first level
    resolution: int = 128             # final level (coarse to fine: the coarse result is upsampled)
                                      # 160 (session 8, six scenes): object F@2cm +0.002..+0.057 but 1.1-3.3 x the
                                      # test-view holes (room junctions, already in the start), lamp shade's hidden
                                      # back lost (hidden R 0.815 -> 0.603); kept 128 (docs/reconstruction.md)
    max_voxels_per_pixel: float = 2.2  # the grid is capped at this many voxels across a pixel's footprint at the far
                                      # surfaces (recon/grid_size.py; the fit log says so): finer voxels lie between
                                      # the pixels' rays, no measurement reaches them (32 px on the 128 grid: a
                                      # lattice of blobs). Cave-chair 32 px (session 11): off L1 0.84 m / F@2cm 0.23,
                                      # 2.2 (grid 65) 0.33 / 0.20, 1.5 (grid 45) 0.24 / 0.08; 64 px at 1.5 (grid 89)
                                      # F@2cm 0.774 -> 0.732, spurious 3.0 -> 7.5 %: 2.2 leaves 64 and 128 px at 128; 0: off
    coarse_fraction: float = 0.0      # fraction of the steps on the coarse level (0: start fine; benchmark)
    bbox_margin_voxels: float = 1.5   # bbox = robust extent of the observed surfaces + this margin
    density_scale: float = 50.0       # sigma = density_scale * softplus(raw), in 1 / m
    raw_free: float = -10.0           # raw density of free space at initialisation (sigma ~ 0.002 / m)
    raw_occupied: float = 4.0         # raw density of occupied space (sigma ~ 200 / m: opaque in 1 voxel)
    surface_slope: float = 4.0        # raw-density ramp per voxel across visible surfaces at init (0: binary);
                                      # 16 left the raw field binary at voxel centres (terraced meshes)
    surface_half_width_voxels: float = 2.0  # the signed-distance ramp spans +- this around visible surfaces
    surface_concave_corners: str = "planes"  # a voxel behind either surface of a concave corner (floor meeting a
                                      # wall) is behind, not the nearest plane's side: 'planes' where the other
                                      # surface lies on a plane bounding the room (unobserved.bounding_planes;
                                      # the white streak at cave-chair's wall foot gone, object metrics within
                                      # 0.001 on six scenes, session 10), 'all' any surface (chair F@2cm 0.818 ->
                                      # 0.802: the chair's own seat/back corner; session 9), 'off'
    surface_hidden_hull_voxels: float = 0.5  # > 0: a hull voxel lying this far (voxels) behind what its four nearest pixels
                                      # saw keeps the hull's occupied start where the nearest measured point's plane
                                      # puts it in front (the ramp emptied it): at a seat meeting its backrest the
                                      # junction's points carry the seat's normal, and the hull behind the backrest's
                                      # foot started at the surface level (cave-chair's two dents; session 18). Its
                                      # hidden-recall cost was the metric scoring the faces where a chair's parts meet;
                                      # with those left out as contact it passes the rule on six scenes: default; 0: off
    surface_seen_through_voxels: float = 2.0  # > 0: a lit-carved voxel the visible surface's ramp would put behind
                                      # the surface (within the half voxel it reaches into carved space) keeps the
                                      # carving's empty start where it lies more than this (voxels) in front of the
                                      # nearest return of the pixel nearest it in direction (init._lit_ramp_seen_through):
                                      # a plane extended past its object's silhouette (dark-room's backrest side fins)
                                      # or mixed with a nearer part. Offline on the start fields (session 21): at 2, of
                                      # dark-room's 8,063 such voxels 77 flagged, none within 2.4 cm of a true surface
                                      # (at 1: also 187 on the walls' grazing views). Six scenes: dark-room objects'
                                      # region 6.5 -> 5.4 %, F@2cm 0.931 -> 0.937, curved-wall 5.1 -> 4.7 %, hidden R at
                                      # most -0.002 (outside-fov): default; 0: off
    explain_in_plane_voxels: float = 0.5  # > 0: a shadowed pair whose spot lies within this many voxels of its pixel's
                                      # tangent plane (a spot on the same wall: light at grazing incidence returns
                                      # nothing, no occluder) is no shadow evidence: the start field (and the spot
                                      # advisor's labels) neither count nor explain it, training leaves it out. Cave-chair:
                                      # 46k of 55k shadowed pairs; their blockers lay on the walls next to the spots
                                      # (the side walls' ridges; restored 392 -> 348, on the walls 38 -> 4). Session 21,
                                      # six scenes (with surface_plane_blocker_voxels): dark-room F@2cm / hidden R 0.931 /
                                      # 0.891 -> 0.938 / 0.909 (the chair's front leg), others within 0.002 / 0.2 point
                                      # (docs/reconstruction.md "Restored blockers on the room's walls"); 0: off
    surface_plane_blocker_voxels: float = 0.5  # > 0: a restored shadow blocker whose centre lies within this many
                                      # voxels of the measured visible surface and of a plane bounding the room (a wall
                                      # voxel a grazing shadowed segment picked: the chair's legs' shadows on the side
                                      # walls) keeps the surface's ramp, not the occupied value, which put the wall half
                                      # a voxel into the room (cave-chair's ridges, session 21, docs/reconstruction.md);
                                      # 0: off
    seen_through_voxels: float = 0.5  # > 0: a restored shadow blocker lying more than this (voxels) in front of the
                                      # nearest return (earliest returns included) of each of its four nearest pixels
                                      # is dropped (lit-carved again): the sensor saw through it though no pixel ray's
                                      # march crossed its voxel (128 px at 3 m miss every third 3.2 cm voxel column).
                                      # Cave-chair: 24 of the 54 restored voxels > 3.2 cm from any true surface, none of
                                      # the 364 within 3.2 cm (the columns 5 cm beside the front legs, the layer beside
                                      # the seat's sides); marking all such voxels camera-free instead cut slits along
                                      # the room's floor-wall edge (session 18); 0: off
    carve_seen_free_beyond_voxels: float = 1.5  # pixel rays farther apart than this (voxels, at the far surfaces):
                                      # camera carving also empties the voxels between them that the pixels'
                                      # footprints saw through (visible_surface_init.seen_free_points). 64 px on the
                                      # 128 grid (2.1): spurious 11.2 -> 2.5 %; 128 px (1.0) is below it (always on,
                                      # 0: chair F@2cm 0.809 -> 0.794 on cave-chair; session 9)
    carve_core: float = 0.5           # a lit ray carves every voxel it crosses (0.3: only through the central
                                      # 0.6 cube; the shadow-consistency pass now keeps thin parts instead)
    carve_spacing_voxels: float = 1.0  # carve with pixels about this many voxels apart at the far surfaces
    explain_shadows: bool = True      # every shadowed segment keeps a blocker: the lit-carved voxel along it
                                      # with the highest shadowed / lit crossing ratio is put back (thin parts)
    explain_camera_free: bool = False  # ... also a voxel the sensor saw through (parts thinner than a pixel). Off
                                      # since session 9: the earliest return (nearest_surface) keeps those parts,
                                      # and these restorations made fins at objects' edges in front of visible
                                      # faces; six scenes 128 px (with footprint carving): organic-occluded spurious
                                      # 2.33 -> 2.03 %, L1 0.0736 -> 0.0521 m, cave-chair hidden R@2cm 0.826 -> 0.880
    explain_score: str = "ratio"      # which carved voxel a shadowed segment gets back: 'ratio' (shadowed / lit
                                      # crossings) or 'spots' (distinct spots' shadows / distinct lit spots + 1)
    explain_lead_voxels: float = 1.5  # a shadowed segment's blocker is also looked for this far before the offset
                                      # its segment skips next to its surface point x (carved voxels only there;
                                      # 1.5 = the whole offset): a leg the sensor sees shadows its own points, and
                                      # the blocker landed on the voxel beside it. Session 10, six scenes 0 -> 1.5:
                                      # F@2cm -0.001..+0.006, hidden R -0.002..+0.008, L1 lower on all six; 0: off
    explain_neighbour_power: float = 0.0  # > 0: a shadowed segment's blocker ranks by shadowed / lit crossings
                                      # times (1 + its occupied 26-neighbours) ^ this: a part the carving took
                                      # touches what stayed of it, the lit inside of the lamp shade does not
                                      # (shadow_blockers.py). Session 13, 0.5, six scenes: F@2cm cave-chair 0.944 ->
                                      # 0.949, curved-wall 0.941 -> 0.951, outside-fov +0.004; thin-structures hidden
                                      # R 0.866 -> 0.859, dark-room 0.902 / 0.827 -> 0.895 / 0.815: opt-in; 0: off
    explain_shared_cluster_voxels: int = 0  # > 0: a shadowed segment whose blocker lies in a cluster (26-neighbours)
                                      # of at least this many restored blockers takes instead, among the blockers
                                      # picked on its own path, the one most segments picked (shadow_blockers.
                                      # shared_blockers): the lamp shade's lid and interior lumps go to its walls.
                                      # Session 16, 200 (only thin-structures' shade is that large): thin-structures
                                      # F@2cm / hidden R 0.838 / 0.865 -> 0.845 / 0.853 (lamp P 0.667 -> 0.702, hidden
                                      # R 0.827 -> 0.802: right wall voxels go with the lumps): opt-in; 0: off
    explain_measured_scale_voxels: float = 0.5  # > 0: a shadowed segment's blocker ranks by shadowed / lit crossings
                                      # over 1 + (its sample's distance to the nearest measured surface point, visible
                                      # or a thin part's) / this many voxels (shadow_blockers.MeasuredSurfacePoints): a
                                      # leg the carving took holds its measured points, the voxel beside it in the
                                      # leg's own shadow (fewer lit crossings) does not; the room's bounding planes'
                                      # points are left out (blockers slid onto the floor beside a foot). Session 17,
                                      # 0.5, six scenes F@2cm / hidden R: cave-chair 0.944 / 0.920 -> 0.950 / 0.954
                                      # (chair F@1cm 0.707 -> 0.721, normals 0.820 -> 0.816), curved-wall +0.006 /
                                      # +0.005, outside-fov +0.008 / +0.027; thin-structures hidden R 0.865 -> 0.854
                                      # (a table leg's column breaks under its top), organic-occluded spurious 1.21 ->
                                      # 1.36 %; with mesh_keep_restored_voxels 3 (which keeps that column) every scene
                                      # passes the default rule: the default since session 17; 0: off
    carve_min_lit: int = 1            # a voxel crossed by at least this many lit secondary rays is free
    lit_path_tolerance_voxels: float = 1.0  # > 0: a lit pair whose measured path is farther than this (voxels; at
                                      # least half a time bin) from the path through its pixel's visible point x got
                                      # its light from another surface in the pixel (a depth edge: dark-room's box
                                      # top edge, the floor 1 m behind it): it carves from where its own path puts
                                      # the surface on the pixel ray and training leaves it out (recon/data.py
                                      # unexplained_lit). Session 12, with the 2-voxel hull inset below, six scenes:
                                      # dark-room F@2cm 0.863 -> 0.902, cave-chair 0.929 -> 0.944, none worse
                                      # (docs/reconstruction.md "Lit pairs at depth edges"); 0: off
    surface_margin_voxels: float = 1.0  # camera free space stops this far before the visible surface
    occupancy_threshold: float = 0.01  # cells whose neighbourhood has sigma * voxel below this are skipped
    occupancy_update_every: int = 25  # steps between occupancy refreshes
    step_voxels: float = 0.5          # ray marching step in voxels
    secondary_offset_voxels: float = 1.5  # secondary rays x -> l skip this much next to x and l
    freeze_measured: bool = False     # True: the optimiser changes only voxels no direct measurement fixed (hidden
                                      # hull, restored blockers, outside the view). Measured (cave-chair 128): the
                                      # result then equals the start - the voxels training improves (hull bands at
                                      # the chair) are the same class as those it tears (wall ramps)
    anchor_weight: float = 0.0        # prior: this x sum of squared raw change on those voxels (0.01: = the start)
    freeze_dilate_voxels: int = 1     # the frozen surface band reaches this many voxels beyond the ramp
    normal_weight: float = 0.01       # surface prior (recon/smoothness.py): this x sum over neighbouring surface
                                      # cells of |n_a - n_b|^2 (n: unit gradient of raw); a sum, so a lump's gradient
                                      # (~0.3 x weight for 2 raw units) passes Adam's eps. 5 scenes 128 px: floor
                                      # tilt p90 3.9-4.7 -> 2.3-3.2 deg, F@2cm -0.008..+0.038, L1 -1.6..+2.0 mm; 0: off
    normal_max_angle_deg: float = 30.0  # ... pairs whose normals differ by more (edges, thin parts) are not smoothed
    lr: float = 0.05                  # Adam on raw density; with the ramp at 4 per voxel the surface moves
                                      # at most lr / 4 voxel a step (0.2 with the old slope 16, same motion).
                                      # Session 2 (slope 16): 0.01 left the initial field
                                      # unchanged, 0.5 tore holes (docs/reconstruction.md, measured)
    rays_per_batch: int = 4096
    steps: int = 100                  # cave-chair 128 (session 5): 100 steps F@2cm 0.834, hidden R 0.764, fewer holes;
                                      # 200: 0.845 / 0.721 and more holes in walls and floor; half the time
    # --- training of the start field (helper quality, session 6) ---
    adam_eps: float = 1e-3            # Adam's epsilon: a voxel moves about lr |g| / (|g| + eps) a step, so the wall
                                      # and floor ramps (|g| ~ 5e-5) stay while the chair's (4e-4 - 1e-3) train.
                                      # Cave-chair 128, 100 steps: 1e-8 (torch default) depth L1 0.075 m, 1e-4
                                      # 0.058, 1e-3 0.055 (hidden R@2cm 0.76 -> 0.83), 1e-2 0.061 (F@2cm 0.78)
    # --- thin parts and hull in the start field (recon/init.py, recon/hull_trim.py) ---
    nearest_free: bool = True         # camera rays are free only up to the pixel's nearest return (earliest
                                      # significant two-bounce return, preprocess): a part under a pixel wide in
                                      # front of the floor is not carved by the pixel that sees past it
    nearest_surface: bool = True      # ... and that nearest surface is occupied where the strongest return lies
                                      # more than a voxel behind it (the thin part itself)
    thin_part_edges: bool = False     # ... also beside a broad visible surface at that range (False: a silhouette
                                      # edge the visible surface holds marks no voxel: no voxel-wide frame round
                                      # the chair). Session 9, six scenes, F@2cm True -> False: cave-chair 0.867
                                      # -> 0.885, curved-wall 0.864 -> 0.890, outside-fov 0.610 -> 0.620, the
                                      # other three within 0.002 (legs and pole whole). With centre 'mean' too:
                                      # cave-chair 0.917 but thin-structures 0.804 -> 0.784 (pole breaks)
    thin_part_centre: str = "coverage"  # ... a thin part's point: 'depth' a quarter pixel footprint behind the
                                      # earliest return (its middle); 'mean' also the mean of its 3 x 3
                                      # neighbours' at the same range; 'seen' only of those seen strongest
                                      # there; 'off' the earliest return. 'mean' with training 'frozen' is the
                                      # default since session 10 (six scenes in docs/reconstruction.md);
                                      # 'coverage': the mean weighted by the part's share of each pixel (its
                                      # background return's deficit; session 11: pole points 1.38 -> 0.82 cm from
                                      # the axis) is the default since session 11, with the mesh's island cleanup
                                      # keeping islands at thin parts (alone its pole broke: thin 0.783)
    thin_part_raw: float = 4.0        # raw density those voxels start at (raw_occupied: 4; higher: the training
                                      # steps of the pixels that see past the part cannot empty it in 100 steps)
    thin_part_radius_voxels: float = 0.0  # > 0: a thin part starts as a tube this many voxels in radius round its points
                                      # (a ramp in the distance to them, `thin_part_signed_distance`: placed to a
                                      # fraction of a voxel); 0: its voxels whole (the part at their centres).
                                      # 0.4 with 'mean' + 'frozen': thin-structures 0.784 / 0.820 (no gain)
    thin_part_training: str = "frozen"  # what training may do to the voxels holding a thin part's point
                                      # (recon/thin_parts.py thin_part_voxels): 'free' as every voxel; 'frozen'
                                      # keep their start value (gradient masked); 'grow' only raise it (the pixels
                                      # seeing past a one-voxel part cannot erode it). With centre 'mean' (session 10):
                                      # thin-structures 0.784 / 0.803 -> 0.788 / 0.832 F@2cm / hidden R (table leg
                                      # kept), cave-chair 0.917 / 0.894, curved-wall 0.920 / 0.928; lamp pole still thin.
                                      # 'frozen' is the default with centre 'mean' (session 10)
    freeze_spot_radius_voxels: float = 4.0  # voxels within this many voxels of a laser spot keep their start value
                                      # (gradient masked): every secondary ray of that spot leaves through them, so
                                      # their summed loss pulls the spot's own (sensor-measured) surface in and
                                      # training dented the wall 1-1.5 cm at every spot (session 18, "Dents at the
                                      # laser spots": 2-3 leave a ring at the rim; 4 the start's flatness, six
                                      # scenes' objects within 0.001); 0: off
    freeze_plane_edges_voxels: float = 2.0  # > 0: voxels within this many voxels of two bounding planes (a room's
                                      # concave edge) and of a measured point keep their start value: with exact
                                      # ranges at the edge (`preprocess.return_centroid_fraction`) training specked
                                      # the 3 cm grid's rounded edge 5-10 mm (session 19); each of the two planes
                                      # needs its own points near the voxel (freeze_masks.plane_edge_voxels: a curved
                                      # wall's facet planes crossing the wall froze a dotted line, session 21); 0: off
    thin_part_half_width_voxels: float = 0.0  # > 0: those voxels start this far inside the surface (a part thinner
                                      # than a voxel); 0: fully occupied. thin-structures 0.3: start better,
                                      # trained worse (F@2cm table 0.792 -> 0.775; training erodes it)
    trim_hull_voxels: int = 8         # > 0: hull voxels no shadowed ray crosses, reachable from measured free space
                                      # through such voxels within this many voxels, start empty (recon/hull_trim.py).
                                      # Cave-chair trained: spurious 1.05 -> 0.49 %, chair unchanged; 0: old start
    hull_opening_voxels: int = 0      # > 0: hidden hull thinner than a ball of this radius (voxels; a morphological
                                      # opening) starts empty where every shadowed segment stays blocked
                                      # (recon/hull_trim.py opening). 2 on organic-occluded's start: spurious
                                      # 1.71 -> 1.31 %, hidden R 0.763 -> 0.718 (session 11); 0: off
    hull_closure: str = "off"         # 'convex': hidden hull outside the convex hull of the voxels measured surfaces
                                      # and shadows' edges place (per connected part) starts empty where every
                                      # shadowed segment stays blocked (recon/hull_trim.py). organic-occluded
                                      # 0.777 / 0.766 / 1.58 % -> 0.778 / 0.773 / 1.39 % (F@2cm / hidden R /
                                      # spurious), the other five within 0.02 % (session 11); 'off'
    hull_closure_margin_voxels: float = 1.0  # ... only hull more than this far outside the convex hull (0: dark-room's
                                      # box lost its back-bottom corner)
    hull_closure_graze_samples: int = 10  # ... a shadowed segment grazes the hull (its voxels are anchors) where it
                                      # crosses at most this many marching samples of it (half a voxel apart)
    hull_closure_min_segments: int = 1  # ... and this many segments graze a voxel
    # --- start field outside the sensor's view and mesh (recon/init.py, recon/unobserved.py) ---
    complete_unobserved: bool = True  # outside the view the planes bounding the observation continue (walls,
                                      # floor, ceiling next to the sensor); False: nothing is put there
    plane_min_support: float = 0.03   # a plane needs this fraction of the visible points (RANSAC inliers)
    plane_tolerance_voxels: float = 0.5  # RANSAC inlier distance; a bounding plane has no point or spot
                                         # more than twice this behind it
    plane_refit_mad: float = 3.0      # each bounding plane fitted again to its inliers within this many robust standard
                                      # deviations of their own scatter (0: RANSAC's fit to all inliers within the
                                      # tolerance). The floor's grazing far rows and junctions (a few mm short)
                                      # tilted it: continued to the sensor it lay 4.8 mm low, dark-room's out-of-view
                                      # floor > 5 mm off; refitted 0.8 mm (session 19, docs/reconstruction.md)
    plane_free_band_voxels: float = 2.0  # the mesh keeps faces facing completed empty space this close
                                         # to a completed plane
    # --- surface placement of the mesh (recon/models.py surface_volume) ---
    mesh_level_shift_voxels: float = 0.0  # the mesh's level moves this far inward (voxels along the ramp). 0.1 on the
                                          # six scenes (session 9): F@2cm +0.001..+0.017, hidden recall -0.004..-0.023;
                                          # off (docs/reconstruction.md "Where the object F-score is lost")
    mesh_hull_inset_voxels: float = 0.35  # the shadow hull's binary boundary (occupied next to free) is placed this
                                          # far inside the voxel face, where the hull is 2 voxels thick (below); 0: off.
                                          # Everywhere (session 9): organic-occluded -0.034 / -0.045 (its hull lies
                                          # inside the blob), so limited to 2-voxel runs
    mesh_hull_inset_max_voxels: int = 2   # ... only where the hull is at most this many voxels thick across the face
                                          # (free again beyond: a 1 cm lamp-shade wall in two voxels); 0: everywhere
    mesh_hull_inset_min_voxels: int = 2   # ... and at least this many (2: a one-voxel leg or blocker keeps its faces).
                                          # Session 12, with lit_path_tolerance_voxels 1: thin-structures F@2cm 0.816 ->
                                          # 0.837; alone it cost dark-room's chair hidden R 0.007 (docs/reconstruction.md)
    mesh_sheet_inset_voxels: float = 0.0  # > 0: sheets of the mesh field (runs of 1..mesh_sheet_max_voxels from saturated
                                          # free space to free space again, at least mesh_sheet_min_in_plane of the 8
                                          # in-plane neighbours occupied: a lamp-shade wall) get their faces this far
                                          # inside the voxel faces (recon/thin_sheets.py): a 1 cm wall lies somewhere in
                                          # its 3.2 cm voxel. Session 14 (re-export of main's fits), 0.35 with max 2:
                                          # thin-structures F@2cm / hidden R 0.838 / 0.866 -> 0.846 / 0.872 (table top's
                                          # underside 0.933 -> 0.945, lamp 0.743 -> 0.748), curved-wall +0.004, but
                                          # cave-chair 0.944 / 0.920 -> 0.940 / 0.906 (its backrest's back, back legs):
                                          # opt-in; 0: off
    mesh_sheet_min_in_plane: int = 4      # ... a sheet: at least this many of the 8 in-plane neighbours occupied (6:
                                          # cave-chair 0.944 / 0.917, but thin-structures only 0.840 / 0.867)
    mesh_sheet_max_voxels: int = 1        # ... and at most this many voxels thick (2: also the two-voxel slabs a wall
                                          # straddling a voxel face leaves, where training left them unsaturated and
                                          # mesh_hull_inset_voxels does not reach them; max 1 at 0.35: 0.843 / 0.865)
    mesh_sheet_unseen_sides: bool = False  # ... and only where neither side is space the sensor saw through (with 0.35,
                                          # max 2: thin-structures 0.847 / 0.872, cave-chair 0.942 / 0.912)
    mesh_hull_shrink_voxels: float = 0.5  # > 0: the mesh vertices of the hidden hull (no measured surface's ramp, thin
                                          # part, restored blocker or camera-free voxel beside them) are smoothed inward,
                                          # at most this far (recon/hull_subvoxel.py; a visual hull over-estimates its
                                          # object); 0: off. Default since session 13, six scenes F@2cm / hidden R:
                                          # dark-room 0.902 / 0.827 -> 0.909 / 0.842 (the box's hidden faces),
                                          # outside-fov 0.643 / 0.602 -> 0.657 / 0.612 (spurious 3.59 -> 3.39 %), the
                                          # other four within 0.001; without the silhouette rule organic-occluded's
                                          # occluder lost 0.06 hidden R (docs/reconstruction.md)
    mesh_keep_restored_voxels: int = 3  # > 0: the mesh's island cleanup also keeps a small island touching a restored
                                      # blocker (voxel_evidence.explain_shadows, label 4) of a connected run (26-neighbours) of at
                                      # least this many restored voxels: a leg's restored one-voxel column breaks where
                                      # one voxel moves, and its lower part fell below the island size (as thin parts
                                      # are kept); lone restored voxels stay specks. Session 13, N = 3: thin-structures
                                      # F@2cm / hidden R 0.838 / 0.866 -> 0.834 / 0.870 (the lamp's interior lumps kept),
                                      # curved-wall F@2cm 0.941 -> 0.935; with explain_neighbour_power 1 it gives the
                                      # table's leg back (table hidden R 0.857 -> 0.892) but the lamp pays: opt-in
                                      # (docs/reconstruction.md "Islands that hold restored blockers"). Session 17:
                                      # 3 is the default with explain_measured_scale_voxels 0.5 (the pair: hidden R
                                      # +0.001 to +0.035 on every scene, F@2cm within 0.002, docs "The chair's legs
                                      # from behind"); 0: off
    mesh_hull_flat_approach: bool = True  # the shrinkable hull's vertices on a flat axis-aligned patch of at least
                                          # mesh_hull_flat_patch_faces voxel faces (no light bounds such a face: marching
                                          # cubes puts it at its voxel layer's outer side) move inward by the light's
                                          # gap: to the middle between the lit segments' nearest approach d to
                                          # the face in the carved voxel beyond it and the layer's inner side,
                                          # (1 - d) / 2 voxel (0 where no lit segment entered that voxel; recon/
                                          # hull_flat.py): a face the light eroded barely moves. Default since session
                                          # 15, six scenes F@2cm / hidden R / spurious: dark-room 0.909 / 0.842 / 0.38 %
                                          # -> 0.924 / 0.882 / 0.29 % (the box's +x face), organic-occluded 0.805 /
                                          # 0.778 -> 0.808 / 0.781, outside-fov 0.657 / 0.612 -> 0.658 / 0.613, the
                                          # others within 0.001 (curved-wall L1 0.0355 -> 0.0359); +0.3-1.4 s of export
                                          # (docs/reconstruction.md); false: off. Session 14's fixed offset (0.25 voxel:
                                          # dark-room 0.927 / 0.894 but outside-fov 0.641 / 0.596) was removed
    mesh_hull_lit_fan: bool = False       # the shrinkable hull's voxels and the lit-carved ones beside them enter marching
                                          # cubes as the share of their 4^3 sub-points inside no spot's lit fan (the
                                          # nearest pair seen from the spot lit and reaching past the point; carved ones
                                          # capped at 0.4, hull ones at least 0.55; recon/lit_fans.py), not whole voxels:
                                          # the light between the pixels' segments, as session 15's oracle hull. Needs
                                          # mesh_hull_shrink_voxels > 0; without mesh_hull_flat_approach the flat
                                          # patches get fans too (organic 0.793 / 0.764: worse). Session 16, F@2cm / hidden R / spurious: organic-
                                          # occluded 0.808 / 0.781 / 1.21 % -> 0.814 / 0.790 / 1.31 % (blob hidden R
                                          # 0.657 -> 0.676, normals 0.895 -> 0.898), thin-structures hidden R 0.865 ->
                                          # 0.861 (the lamp): opt-in, +1-3 s of export (docs/reconstruction.md); false: off
    mesh_unplaced_taubin_iterations: int = 0  # > 0: after the hull's inward smoothing, this many Taubin passes of every
                                          # mesh vertex no camera ray places (not beside a visible surface's ramp or
                                          # point voxel or a thin part; recon/hull_unplaced.py), each kept within
                                          # mesh_unplaced_max_voxels of its start and out of camera-free space: the
                                          # hidden hull's lumps sit on hull voxels training lowered part-way and on
                                          # restored blockers, which the saturated-hull smoothings left alone
                                          # (session 17: docs/reconstruction.md "The hidden hull's lumps"). 30
                                          # passes, re-exports of main15: every object's normals +0.001-0.010 (blob
                                          # 0.895 -> 0.902), organic-occluded / thin-structures F@2cm +0.003, but
                                          # hidden R curved-wall 0.957 -> 0.950, outside-fov 0.613 -> 0.608: opt-in; 0: off
    mesh_unplaced_max_voxels: float = 1.0  # ... the largest move, voxels (in (0, 2])
    mesh_unplaced_silhouettes: bool = True  # ... and vertices beside camera-free voxels (silhouettes) stay too (false:
                                          # organic-occluded hidden R 0.781 -> 0.777, the occluder's silhouette face)
    mesh_plane_snap_voxels: float = 1.0  # > 0: mesh vertices no camera ray places (recon/hull_planes.py) within this
                                          # many voxels of a plane bounding the observation, their normal within 20
                                          # degrees of its, go onto it: the floor behind dark-room's box lay in furrows
                                          # 1-2 cm deep (lit segments grazing whole voxels). dark-room room > 5 mm off
                                          # 3.79 -> 3.42 % (the occluded floor 0.45 -> 0.19), objects within 0.001.
                                          # Runs after mesh_hull_shrink_voxels' export step (also where that is 0,
                                          # since session 20; session 19, docs/reconstruction.md "Bumps on a dark
                                          # room's walls"); 0: off
    mesh_hull_flat_patch_faces: int = 15  # ... the patch size (coplanar faces of hull voxels towards carved space)
    mesh_hull_shrink_graze_samples: int = 4  # ... except hull voxels a shadowed segment grazes (crosses at most this
                                          # many marching samples of the hull: the shadow's edge); 0: none excepted
                                          # (with the silhouette rule 0 and 4 differ by <= 0.001 on organic / dark-room)
    # --- visible surfaces of the mesh (session 7) ---
    mesh_front_of_visible: bool = True  # the mesh also keeps faces facing the voxels just in front of a measured
                                        # visible point (along its normal): cave-chair start field, sensor
                                        # view pixels the mesh misses (pin-holes at the grazing ceiling next
                                        # to the back wall) 87 -> 3
    mesh_seen_free: bool = True       # ... and faces facing a point the sensor's pixel footprints saw through
                                      # (between pixel rays; visible_surface_init.seen_free_points): curved-wall
                                      # and 64 px sensors' pin-holes (docs/reconstruction.md, session 9)
    seen_free_corners: bool = True    # ... where the four pixels' points meet in a concave corner, the surface
                                      # between them is the nearest of their tangent planes along the ray (the
                                      # corner itself), not the chord that cuts it (mesh test and 64 px carving;
                                      # cave-chair 64 px misses 16352 -> 14806, session 10)
