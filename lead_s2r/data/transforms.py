"""Schema v1 sample -> model input tensors (the :class:`lead_s2r.models.inputs.Batch` contract), per source.

:class:`SourceTransform` is a pure function of one decoded sample and the model's
:class:`~lead_s2r.models.input_spec.InputSpec`: the native-rate future resampled to the model's grid, cameras laid out
in the input image (:mod:`lead_s2r.data.camera_input`), LiDAR rasterised onto the BEV grid (:mod:`lead_s2r.data.lidar`),
and the labels moved onto the model's grids in LEAD's encoding (:mod:`lead_s2r.data.lead_labels`,
:mod:`lead_s2r.data.lead_centernet`, :mod:`lead_s2r.data.radar`, :mod:`lead_s2r.data.lead_route`);
:func:`~lead_s2r.data.collate.collate` stacks them. A label a sample does not have is left out, and the loss masks it.

Tensors are lean (the loader builds and stacks every byte on the CPU): the image uint8, the LiDAR raster uint8 hit
counts, class maps the stored uint8 ids (:data:`~lead_s2r.models.inputs.IGNORE_CLASS` where there is no label), and a
depth or semantic label smaller than the image under a plain resize
(:attr:`~lead_s2r.data.camera_layout.CameraLayout.whole`) is not upsampled here; the model and the losses scale, widen
and resize them on the device. Images stay in the (H, W, 3) order decoders write: a sample's ``rgb`` is a (3, H, W) view
of it and a batch's a channels-last (B, 3, H, W) tensor, the memory format convolutions run fastest in on the GPU. With
``inputs_on_device`` camera JPEGs the training device can lay out are not decoded at all: the bytes go to the device
with their rig's layout, and so do the LiDAR points, unrasterised (:mod:`lead_s2r.data.device_inputs`).
"""

from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
import torch

from lead_s2r.data.camera_input import CameraInput
from lead_s2r.data.camera_layout import CameraLayout, label_on_layout
from lead_s2r.data.collate import IGNORE_VALUE
from lead_s2r.data.device_inputs import LIDAR_POINTS, RGB_JPEG, RGB_LAYOUT, jpeg_tensor
from lead_s2r.data.lead_centernet import lead_centernet_targets
from lead_s2r.data.lead_labels import (
    bev_labels,
    draw_lead_boxes,
    lead_box_classes,
    lead_hdmap_canvas,
    radar_priority,
    traffic_light_classes,
)
from lead_s2r.data.lead_origin import centre_shift, to_centre_origin
from lead_s2r.data.lead_route import lead_route
from lead_s2r.data.lidar import lidar_xy, rasterize_lidar
from lead_s2r.data.radar import MAX_RADAR_POINTS, pad_points, radar_targets
from lead_s2r.errors import UserError
from lead_s2r.geometry import resample
from lead_s2r.models.input_spec import InputSpec
from lead_s2r.schema import BoxClass, command4


@dataclass
class SourceTransform:
    """Turns samples of one source into the tensors a model reading ``spec`` takes.

    Args:
        source: the source name the model knows (its trajectory grid and label space), e.g. "carla".
        spec: what the model reads (image size, BEV grid, trajectory grids, labels): its config's
            :func:`~lead_s2r.models.input_spec.input_spec`.
        cameras: camera fields stitched left to right into the input image (without the ``cam_`` prefix).
        inputs_on_device: leave the camera JPEGs the training device can lay out encoded (``rgb_jpeg`` + ``rgb_layout``,
            :attr:`~lead_s2r.data.camera_input.CameraPlan.on_device`) and the LiDAR points unrasterised
            (``lidar_points``), for :mod:`~lead_s2r.data.device_inputs`.
    """

    source: str
    spec: InputSpec
    cameras: list[str] = field(default_factory=lambda: ["carla_mosaic"])
    inputs_on_device: bool = False
    camera: CameraInput = field(init=False, repr=False)

    def __post_init__(self) -> None:
        spec = self.spec
        self.camera = CameraInput(self.source, self.cameras, spec.image_size, spec.vertical_fov_deg, spec.equal_tiles)

    @property
    def fields(self) -> list[str]:
        """The sample fields this transform reads, so loaders decode nothing else (``meta`` always comes)."""
        spec, space = self.spec, self.spec.space(self.source)
        radar_targets = spec.radar and self.source in spec.radar_sources
        wanted = {
            "lidar": spec.lidar_raster,
            "radar": spec.radar,
            "boxes": radar_targets or space in spec.lead_box_classes or self.lead_carla,
            "bev_semantic": space in spec.bev_semantic_classes,
        }
        fields = ["future", "target_points", "route"] + [name for name, read in wanted.items() if read]
        fields += [f"cam_{camera}" for camera in self.cameras]
        if len(self.cameras) == 1:
            if space in spec.depth_sources:
                fields.append(f"depth_{self.cameras[0]}")
            if space in spec.semantic_classes:
                fields.append(f"semantic_{self.cameras[0]}")
        return fields

    def __call__(self, sample: dict[str, Any]) -> dict[str, Any]:
        lidar_shift = 0.0
        if self.lead_carla:  # LEAD's CARLA frame: origin at the vehicle centre; the LiDAR moved in its raster
            sample, lidar_shift = to_centre_origin(sample, keep=("lidar",)), centre_shift(sample)
        meta = sample["meta"]
        ego = meta["ego"]
        out: dict[str, Any] = {
            "__key__": sample["__key__"],
            "__dataset__": meta["dataset"],
            "speed": torch.scalar_tensor(float(ego["speed"])),  # torch.tensor's result, cheaper (docs/benchmarks.md)
            "acceleration": torch.from_numpy(np.array(ego["acceleration"], np.float32)),
            "command": torch.scalar_tensor(int(command4(ego["command"])), dtype=torch.int64),
        }
        if self.lead_carla:  # LEAD's CARLA network tells lane following from going straight, and lane changes apart
            out["command_full"] = torch.scalar_tensor(int(ego["command"]), dtype=torch.int64)
            out["origin_x"] = torch.scalar_tensor(float(meta["vehicle"]["rear_axle_to_center"]))
        if self.cameras:  # a model without cameras (the ego-status MLP) decodes no image
            plan = self.camera.plan(sample)
            if self.inputs_on_device and plan.on_device:
                out[RGB_JPEG] = [jpeg_tensor(self.camera.jpeg(sample, camera)) for camera in self.cameras]
                out[RGB_LAYOUT] = plan.layout
            else:
                out["rgb"] = self.camera.image(sample, plan)
        out.update(self.target_points(sample))
        spec = self.spec
        lead = self.lead_carla_boxes(sample) if self.lead_carla and "boxes" in sample else None
        if spec.lidar_raster and self.inputs_on_device:
            out[LIDAR_POINTS] = lidar_xy(sample.get("lidar"), lidar_shift)
        elif spec.lidar_raster:
            out["lidar_bev"] = torch.from_numpy(rasterize_lidar(sample.get("lidar"), spec.bev, lidar_shift))[None]
        if spec.radar:
            out.update(pad_points("radar", sample.get("radar"), MAX_RADAR_POINTS, 5))
            if "radar" in sample and "boxes" in sample and self.source in spec.radar_sources:
                out.update(self.radar_targets(sample, lead))
        if "future" in sample:
            out.update(self.trajectory(sample["future"]))
        if "route" in sample:
            out.update(lead_route(sample["route"], spec.num_route_points))
        extras = _extras(meta)
        if extras.get("target_speed") is not None:
            out["target_speed"] = torch.scalar_tensor(float(extras["target_speed"]))
            out["target_speed_valid"] = torch.scalar_tensor(True, dtype=torch.bool)
            # the expert's brake flag: LEAD's target-speed label is then the 0 m/s class whatever the speed
            out["brake"] = torch.scalar_tensor(bool(extras.get("brake", False)), dtype=torch.bool)
        space = spec.space(self.source)
        if "bev_semantic" in sample and space in spec.bev_semantic_classes:
            out["bev_semantic"] = torch.from_numpy(self.bev_semantic(sample, lead))
        if "boxes" in sample and space in spec.lead_box_classes:
            out.update(self.lead_boxes(sample, spec.lead_box_classes[space], lead))
        if len(self.cameras) == 1:
            out.update(self.perspective_labels(sample, space, plan.layout))
        return out

    @property
    def lead_carla(self) -> bool:
        """Whether this source's labels go into LEAD's CARLA class tables (:mod:`lead_s2r.data.lead_labels`)."""
        return self.spec.lead_carla_labels is not None and self.spec.space(self.source) == "carla"

    def lead_carla_boxes(self, sample: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        """Per box of the sample: the BEV class of a traffic light affecting the ego (-1: not a light; see
        :func:`~lead_s2r.data.lead_labels.traffic_light_classes`) and LEAD's box class (-1: LEAD detects none)."""
        classes = sample["boxes"][:, 9].astype(np.int64)
        lights = traffic_light_classes(classes, _extras(sample["meta"]))
        return lights, lead_box_classes(classes, self.spec.lead_carla_labels == "leaderboard", lights)

    def bev_semantic(self, sample: dict[str, Any], lead: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray:
        """The stored BEV classes on the BEV grid; for LEAD's CARLA head its 13 classes with the boxes drawn over
        (``lead``: :meth:`lead_carla_boxes`, None without boxes)."""
        bev = sample["meta"]["bev"]
        if not self.lead_carla:
            return bev_labels(sample["bev_semantic"], bev, self.spec.bev)
        if bev.get("classes") != "carla_hdmap":
            raise UserError(
                f"sample {sample['__key__']!r}, field 'meta.bev.classes': LEAD's CARLA BEV head is built from the "
                f"'carla_hdmap' classes, not {bev.get('classes')!r}; convert the data with the carla_lead adapter"
            )
        boxes = sample.get("boxes", np.zeros((0, 10), np.float32))
        lights = np.zeros(0, np.int64) if lead is None else lead[0]
        leaderboard = self.spec.lead_carla_labels == "leaderboard"
        canvas = lead_hdmap_canvas(sample["bev_semantic"], bev, self.spec.bev, leaderboard)
        return draw_lead_boxes(canvas, boxes, self.spec.bev, leaderboard, lights)  # = lead_bev_labels, from the raster

    def lead_boxes(
        self, sample: dict[str, Any], num_classes: int, lead: tuple[np.ndarray, np.ndarray] | None
    ) -> dict[str, torch.Tensor]:
        """LEAD's CenterNet targets: vehicles only for a one-class head (NAVSIM's), else LEAD's CARLA classes
        (``lead``: :meth:`lead_carla_boxes`)."""
        boxes = sample["boxes"]
        if num_classes == 1:
            classes = np.where(boxes[:, 9].astype(np.int64) == BoxClass.VEHICLE, 0, -1)
        else:
            classes = (lead or self.lead_carla_boxes(sample))[1]
        bins = self.spec.lead_yaw_bins
        return lead_centernet_targets(boxes, classes, self.spec.bev, num_classes, bins, velocity=self.lead_carla)

    def radar_targets(
        self, sample: dict[str, Any], lead: tuple[np.ndarray, np.ndarray] | None
    ) -> dict[str, torch.Tensor]:
        """Radar detection targets; for LEAD's CARLA network (``lead``: :meth:`lead_carla_boxes`) only of the boxes
        LEAD detects, in LEAD's order."""
        boxes = sample["boxes"]
        if lead is None:
            return radar_targets(sample["radar"], boxes)
        detected = lead[1] >= 0
        return radar_targets(sample["radar"], boxes[detected], radar_priority(lead[1][detected]))

    def target_points(self, sample: dict[str, Any]) -> dict[str, torch.Tensor]:
        points = sample.get("target_points")
        if points is None:
            return {"target_points": torch.zeros(3, 2), "target_points_valid": torch.zeros(3, dtype=torch.bool)}
        valid = np.isfinite(points).all(axis=1)
        return {
            "target_points": torch.from_numpy(np.where(valid[:, None], points, 0).astype(np.float32)),
            "target_points_valid": torch.from_numpy(valid),
        }

    def trajectory(self, future: np.ndarray) -> dict[str, torch.Tensor]:
        """Waypoints (and headings, where the source has them) on the source's output grid, masked beyond the
        recorded horizon."""
        times = np.asarray(self.spec.trajectory_grids[self.source].times)
        knots = np.vstack([np.zeros((1, 4), np.float32), future])  # the ego sits at the origin at t = 0
        poses, valid = resample(knots[:, 0], knots[:, 1:], times, angle_columns=(2,))
        out = {
            "waypoints": torch.from_numpy(nan_to_zero(poses[:, :2])),
            "waypoints_valid": torch.from_numpy(valid),
        }
        heading_valid = valid & np.isfinite(poses[:, 2])
        if heading_valid.any():  # a source without headings (WOD-E2E) must not dilute the heading loss of others
            out["headings"] = torch.from_numpy(nan_to_zero(poses[:, 2]))
            out["headings_valid"] = torch.from_numpy(heading_valid)
        return out

    def perspective_labels(self, sample: dict[str, Any], space: str, layout: CameraLayout) -> dict[str, torch.Tensor]:
        """Depth (float32 metres, 0 = no label) and semantic ids (the stored uint8, :data:`IGNORE_CLASS` = ignore) of
        the single input camera, laid out on the input image's pixel grid exactly as the image is, except that a label
        smaller than the image under a plain resize (:attr:`CameraLayout.whole`) stays at its own resolution: the
        loss resizes it on the device (:func:`~lead_s2r.models.inputs.on_image_grid`), as
        :func:`~lead_s2r.data.camera_layout.render` would have."""
        camera = self.cameras[0]
        out = {}
        depth = sample.get(f"depth_{camera}")
        if depth is not None and space in self.spec.depth_sources:
            encoding = sample["meta"].get("depth", {})
            metres = depth.astype(np.float32) / 255.0 * float(encoding.get("max_m", self.spec.max_depth))
            out["depth"] = torch.from_numpy(label_on_layout(layout, metres, cv2.INTER_LINEAR, 0.0))
        semantic = sample.get(f"semantic_{camera}")
        if semantic is not None and space in self.spec.semantic_classes:
            out["semantic"] = torch.from_numpy(
                label_on_layout(layout, semantic, cv2.INTER_NEAREST, IGNORE_VALUE["semantic"])
            )
        return out


def _extras(meta: dict[str, Any]) -> dict[str, Any]:
    return meta["extras"].get(meta["dataset"], {})


def nan_to_zero(values: np.ndarray) -> np.ndarray:
    """float64 ``values`` (resampled, NaN where masked) as float32 with NaN as 0.

    Equal to ``np.nan_to_num(values).astype(np.float32)`` (whose +-float64 max for +-inf round to +-inf in float32)
    in three numpy calls instead of a dozen: this runs twice per sample on arrays of a few dozen numbers."""
    out = values.astype(np.float32)
    out[np.isnan(out)] = 0.0
    return out
