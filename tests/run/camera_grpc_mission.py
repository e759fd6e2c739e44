"""MAVSDK's camera plugin, the gRPC API (MAVSDK-Python < 4, ``mavsdk-grpc``; test data for ``test_camera.py``):
find the camera, photo mode, take a photo, list the photos; print what it got."""

import asyncio

from mavsdk import System
from mavsdk.camera import Mode, PhotosRange


async def run() -> None:
    drone = System()
    await drone.connect(system_address="udpin://0.0.0.0:14540")
    async for state in drone.core.connection_state():
        if state.is_connected:
            break
    async for cams in drone.camera.camera_list():
        if cams.cameras:
            break
    print(f"CAMERAS {[(c.component_id, c.model_name) for c in cams.cameras]}", flush=True)
    cid = cams.cameras[0].component_id
    await drone.camera.set_mode(cid, Mode.PHOTO)
    await drone.camera.take_photo(cid)
    await asyncio.sleep(1)
    for p in await drone.camera.list_photos(cid, PhotosRange.ALL):
        print(f"PHOTO {p.index} {p.position.latitude_deg:.7f} {p.position.longitude_deg:.7f} {p.file_url}", flush=True)


if __name__ == "__main__":
    asyncio.run(run())
