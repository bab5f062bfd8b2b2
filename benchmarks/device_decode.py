"""A batch of CARLA mosaics decoded in the loader (libjpeg-turbo, CPU) against on the GPU (nvJPEG).

.venv/bin/python benchmarks/device_decode.py --batch-size 8 --repeats 20

Per batch: CPU ms of the loader's decode and stacking; with a CUDA device also the device path's wall ms
(synchronised) and the CPU ms it leaves on the host, and how far nvJPEG's pixels are from libjpeg-turbo's (mean and
max absolute difference, levels of 255). The mosaics are 1152x384 q=90 JPEGs of a smooth scene with sensor-like
noise (``camera_input.scene_jpeg``), each a little different. Without a GPU the device rows are skipped.
"""

import argparse
import time

import torch
from camera_input import scene_jpeg
from cpu_time import cpu_times_ms

from lead_s2r.data.camera_layout import Tile, camera_layout
from lead_s2r.data.device_inputs import RGB_JPEG, RGB_LAYOUT, decode_images, decode_rgb, jpeg_tensor


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch-size", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args()
    torch.set_num_threads(1)  # as in a dataloader worker
    jpegs = [jpeg_tensor(scene_jpeg(384, 1152, seed)) for seed in range(args.batch_size)]
    print(f"{args.batch_size} mosaics, {sum(len(j) for j in jpegs) / len(jpegs) / 1e3:.0f} KB each")
    mosaic = camera_layout((((384, 1152), (Tile(0, 1152),)),), (384, 1152), None)  # the model's image as stored

    def in_loader() -> torch.Tensor:
        images = decode_rgb(jpegs, "cpu")
        return torch.stack([image.permute(1, 2, 0) for image in images]).permute(0, 3, 1, 2)

    loader_ms = cpu_times_ms(in_loader, args.repeats)
    print(f"loader (CPU): {loader_ms.mean():.2f} ms CPU per batch, {loader_ms.mean() / args.batch_size:.2f} per image")
    if not torch.cuda.is_available():
        print("no CUDA device: the nvJPEG rows need a GPU")
        return

    def on_device() -> torch.Tensor:
        rgb = decode_images({RGB_JPEG: [[jpeg] for jpeg in jpegs], RGB_LAYOUT: [mosaic] * len(jpegs)}, "cuda")["rgb"]
        torch.cuda.synchronize()
        return rgb

    on_device()  # nvJPEG's handles and buffers
    wall, cpu = time.perf_counter(), time.process_time()
    for _ in range(args.repeats):
        rgb = on_device()
    wall_ms = (time.perf_counter() - wall) / args.repeats * 1e3
    cpu_ms = (time.process_time() - cpu) / args.repeats * 1e3
    print(f"device ({torch.cuda.get_device_name()}): {wall_ms:.2f} ms wall, {cpu_ms:.2f} ms host CPU per batch")
    difference = (rgb.cpu().int() - in_loader().int()).abs()
    print(f"nvJPEG vs libjpeg-turbo: mean {difference.float().mean():.3f}, max {int(difference.max())} levels")


if __name__ == "__main__":
    main()
