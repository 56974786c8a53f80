#!/usr/bin/env bash
# The device command of issue #31 item 5: bench/first_images_gpu.py on the lent GPU machine, in one call.
# Needs, carried (both git-ignored): .whl/ (site312.tar.xz from bench/first_images_gpu_pack.sh, and the NEXT
# checkpoint next/next.json + .safetensors) and .gl/ (the EGL debs, .library/device/README.md).
#
#   run(command="bash bench/first_images_gpu.sh [ARGS of first_images_gpu.py]", carry=[".whl", ".gl"])
#
# Results: $OUT/results.json, table.md, first_results.json, first_bench.png, log.txt (at most 8 files back).
set -u
T0=$(date +%s)
stamp() { echo "[setup +$(( $(date +%s) - T0 )) s] $*"; }
OUT=${OUT:-/tmp/first_images_out}
mkdir -p "$OUT"
for f in .gl/*.deb; do dpkg -x "$f" /; done
ldconfig
mkdir -p /tmp/site && tar xJf .whl/site312.tar.xz -C /tmp/site || exit 3
export PYTHONPATH=$PWD:/tmp/site:/tmp/site/cmeel.prefix/lib/python3.12/site-packages
export MUJOCO_GL=egl PYTHONUNBUFFERED=1 FACTR2_CACHE=/tmp/factr2cache PYTHONDONTWRITEBYTECODE=1
NV=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
[ -f $NV ] && export __EGL_VENDOR_LIBRARY_FILENAMES=$NV
stamp "packages and EGL"
nvidia-smi -L; nproc; python3 --version
python3 - <<'EOF' || exit 4
import time
t = time.perf_counter()
import mujoco, pinocchio, can, mcap, ruckig, dynamixel_sdk, torch  # noqa: F401
from hardware.cameras.mujoco_camera import make_renderer
m = mujoco.MjModel.from_xml_string("<mujoco><worldbody><light pos='0 0 1'/><geom size='.1'/></worldbody></mujoco>")
r, backend = make_renderer(m, 320, 240)
d = mujoco.MjData(m)
r.update_scene(d)
img = r.render()
try:
    import OpenGL.GL as gl
    glr = gl.glGetString(gl.GL_RENDERER)
except Exception as e:  # only informative
    glr = repr(e)
print(f"mujoco {mujoco.__version__}, pinocchio {pinocchio.__version__}, torch {torch.__version__}, cuda "
      f"{torch.cuda.is_available()} ({torch.cuda.get_device_name(0) if torch.cuda.is_available() else '-'}); "
      f"render {backend} {img.shape} mean {img.mean():.1f}, GL renderer {glr}, "
      f"{time.perf_counter() - t:.1f} s")
EOF
stamp "checks done"
RUN=/tmp/first_images_run
export FIRST_IMAGES_PARTIAL=$OUT/partial.json
python3 -m bench.first_images_gpu --out $RUN --next .whl/next/next.json "$@" 2>&1 | grep -v "follower on hold" | tee "$OUT/log.txt"
rc=${PIPESTATUS[0]}
for f in results.json table.md first_results.json first_bench.png; do [ -f $RUN/$f ] && cp $RUN/$f "$OUT/"; done
stamp "done (rc $rc)"
exit $rc
