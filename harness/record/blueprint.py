"""The layout of the 3D view: the swarm in 3D (with a map tab), the series beside it, the events below."""

from __future__ import annotations

from typing import Any


def blueprint(n_vehicles: int) -> Any:
    """A ``rerun.blueprint.Blueprint`` for a run of ``n_vehicles`` (the map tab works only with map tiles)."""
    import rerun.blueprint as rrb

    scene = rrb.Spatial3DView(name="swarm (3D)", origin="world")  # the eye fits the scene; double-click refits
    geo = rrb.MapView(name="map", origin="map")
    series = [
        rrb.TimeSeriesView(name=title, origin=f"series/{path}")
        for title, path in (
            ("altitude (m)", "altitude_m"),
            ("speed (m/s)", "speed_m_s"),
            ("battery (%)", "battery_pct"),
            ("link delivery (%)", "link_delivery_pct"),
            ("real-time factor", "real_time_factor"),
        )
    ]
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Tabs(scene, geo, active_tab=0),
                rrb.TextLogView(name="events", origin="events"),
                row_shares=[5, 1],
            ),
            rrb.Vertical(*series),
            column_shares=[3, 2],
        ),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="collapsed", timeline="sim_time"),  # collapsed: the time bar alone, for scrubbing
    )
