#!/usr/bin/env bash
# Packs the Python packages the GPU machine lacks (issue #31 item 5) into .whl/site312.tar.xz for the device
# tool's 64 MiB carry: Python 3.12 x86-64 wheels installed into a folder here, stripped of what neither
# import nor run needs (headers, CMake files, static libraries, MuJoCo Studio, duplicated .so versions),
# then xz. On the device: tar xJf .whl/site312.tar.xz -C /tmp/site; PYTHONPATH=/tmp/site:/tmp/site/cmeel.prefix/lib/python3.12/site-packages
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
PLAT="--platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 --platform any"
PKGS="mujoco==4.0.0 mujoco-core==4.0.0 mujoco-studio==4.0.0 glfw==2.11.0 PyOpenGL==3.1.10 pin==4.1.0 libpinocchio==4.1.0
 coal==3.0.3 libcoal==3.0.3 eigenpy==3.13.0 cmeel==0.62.0 cmeel-boost==1.90.0 cmeel-assimp==6.0.5 cmeel-console-bridge==1.0.2.3
 cmeel-octomap==1.10.0 cmeel-qhull==8.0.2.1 cmeel-tinyxml2==11.0.0 cmeel-urdfdom==6.0.0 cmeel-zlib==1.3.2 mcap==1.6.0 lz4==4.4.5
 zstandard==0.25.0 python-can==4.6.1 dynamixel-sdk==4.1.0 pyserial==3.5 ruckig==0.19.4"
W=/tmp/first_gpu_wheels; S=/tmp/first_gpu_site
mkdir -p $W .whl
$PY -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp $PLAT -d $W $PKGS
rm -rf $S
$PY -m pip install -q --no-deps --no-compile --only-binary=:all: --python-version 3.12 --implementation cp $PLAT \
    --target $S $W/*.whl
cd $S
rm -rf cmeel.prefix/include cmeel.prefix/share cmeel.prefix/bin cmeel.prefix/lib/cmake cmeel.prefix/lib/pkgconfig \
       mujoco/studio mujoco/doc bin include
find . -name '*.a' -delete
find . -name '__pycache__' -prune -exec rm -rf {} +
# pip copies each .so symlink as a file: the versioned name keeps the bytes, the others become links
find cmeel.prefix/lib -maxdepth 1 -type f -name 'lib*.so*' | sort | while read -r f; do
    [ -L "$f" ] && continue
    base=${f%%.so*}.so
    for g in "$base" "$base".*; do
        [ -f "$g" ] && [ ! -L "$g" ] && [ "$g" != "$f" ] && cmp -s "$f" "$g" && ln -sf "$(basename "$f")" "$g" || true
    done
done
cd - >/dev/null
tar -C $S -cf - . | xz -T2 -6 > .whl/site312.tar.xz
du -sh $S .whl/site312.tar.xz
