"""MAVSDK's camera plugin, native API (mavsdk >= 4; test data for ``test_camera.py``): find the camera, photo
mode, take a photo, list the photos; print what it got."""

import time

from mavsdk import ComponentType, Configuration, Mavsdk
from mavsdk.plugins.camera import Camera, Mode, PhotosRange


def main() -> None:
    mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    mavsdk.add_any_connection("udpin://0.0.0.0:14540")
    system = mavsdk.first_autopilot(10.0)
    if system is None:
        raise SystemExit("no autopilot found")
    camera = Camera(system)
    deadline = time.monotonic() + 20
    while not camera.camera_list().cameras and time.monotonic() < deadline:
        time.sleep(0.2)
    cams = camera.camera_list().cameras
    print(f"CAMERAS {[(c.component_id, c.model_name) for c in cams]}", flush=True)
    cid = cams[0].component_id
    camera.set_mode(cid, Mode.PHOTO)
    camera.take_photo(cid)
    time.sleep(1)
    photos = camera.list_photos(cid, PhotosRange.ALL)
    for p in photos:
        print(f"PHOTO {p.index} {p.position.latitude_deg:.7f} {p.position.longitude_deg:.7f} {p.file_url}", flush=True)
    mavsdk.destroy()


if __name__ == "__main__":
    main()
