#!/usr/bin/env python3
"""MAVFTP (as MAVSDK's ftp examples): list the vehicle's root, walk into its log directory, download the
ULog being written (burst mode), upload a file and check it, and report what it found (gRPC API)."""

import asyncio
import os
import tempfile

from mavsdk import System
from mavsdk.ftp import FilesystemEntry

DIR = FilesystemEntry.EntryType.DIRECTORY


def show(entries) -> str:
    return ", ".join(f"{e.name}/" if e.entry_type == DIR else f"{e.name} ({e.size_bytes} B)" for e in entries)


async def run() -> None:
    drone = System()
    await drone.connect(system_address="udpin://0.0.0.0:14540")
    async for state in drone.core.connection_state():
        if state.is_connected:
            print("-- Connected to drone!")
            break
    ftp = drone.ftp
    print("-- / :", show((await ftp.list_directory("/")).entries))
    days = (await ftp.list_directory("/log")).entries
    print("-- /log :", show(days))
    day = next(e.name for e in days if e.entry_type == DIR)
    logs = (await ftp.list_directory(f"/log/{day}")).entries
    print(f"-- /log/{day} :", show(logs))
    name = next(e.name for e in logs if e.name.endswith(".ulg"))
    out_dir = os.environ.get("HARNESS_RUN_DIR", ".")
    down = os.path.join(out_dir, "ftp-download")
    os.makedirs(down, exist_ok=True)
    last = None
    async for progress in ftp.download(f"/log/{day}/{name}", down, use_burst=True):
        last = progress
    print(f"-- Downloaded /log/{day}/{name}: {last.bytes_transferred} of {last.total_bytes} bytes")
    with tempfile.TemporaryDirectory() as tmp:
        local = os.path.join(tmp, "hello.txt")
        with open(local, "w") as f:
            f.write("uploaded by a mission\n" * 50)
        await ftp.create_directory("/etc/mission")
        async for _ in ftp.upload(local, "/etc/mission"):
            pass
        print("-- Uploaded, identical:", await ftp.are_files_identical(local, "/etc/mission/hello.txt"))
    await ftp.rename("/etc/mission/hello.txt", "/etc/mission/renamed.txt")
    print("-- /etc/mission :", show((await ftp.list_directory("/etc/mission")).entries))
    await ftp.remove_file("/etc/mission/renamed.txt")
    await ftp.remove_directory("/etc/mission")
    print("-- /etc after clean-up:", show((await ftp.list_directory("/etc")).entries))


if __name__ == "__main__":
    asyncio.run(run())
