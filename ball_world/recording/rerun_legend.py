"""The view's legend: a text panel beside the arena naming every mark it draws.

A newcomer who opens the page sees discs, lines, dots, arrows, rings and grey cells; the
legend says what each is, for the world being shown (robots, a map, trails), in the
theme's own text colour (a Markdown TextDocument, so it reads on both themes). docs/view.md
says the same at more length.
"""
import rerun as rr

from ball_world.msgs.bumper_markers import BUMPER_SHOWN

#: Entity path of the legend (outside the arena: a panel of its own).
LEGEND = 'legend'


def legend_text(parameters, impulse_seconds, plot_period):
    """Markdown naming each mark the view of a world of these parameters draws."""
    agents = bool(parameters.get('agents'))
    lines = ['**What the view draws**', '',
             '- **discs**: balls in their own colours, named in dark tags'
             + (' (robots always)' if agents else '')]
    trail = float(parameters.get('rerun.trail_seconds') or 0.0)
    if trail:
        lines.append(f'- **thin line behind a ball**: its path over the last {trail:g} s (trail)')
    if parameters.get('rerun.velocities'):
        lines.append("- **arrow in a ball's colour**: its velocity")
    if agents:
        lines += [
            "- **light orange arrow, dark edge**: a robot's heading",
            "- **blue dots**: a robot's lidar hits (every second beam); "
            '**faint blue lines**: some rays (fewer with more robots, none from 13 on)',
            f'- **violet arrow and tag**: a bumper hit on a robot ({BUMPER_SHOWN:g} s)',
            "- **green rings, dark edge**: a tracker's tracks (the demo's: what `ball_1` "
            'sees)']
    if parameters.get('map'):
        unknown = ('solid' if parameters.get('map.unknown_solid', True) else 'free')
        lines += ["- **grey cells**: the map's walls; **faint grey cells**: its unknown "
                  f'cells ({unknown})']
    lines += [
        "- **grey lines**: the arena's walls; ticks and numbers: a ruler in metres",
        f'- **pink arrow, dark edge, and tag**: a push from outside ({impulse_seconds:g} s)',
        '- **plots**: energy' + (
            ", which the robots' drives put in and take out; the rest stays 0 unless pushed"
            if agents else ', which collisions keep: flat unless something pushes')
        + (f'; a live view gets them every {plot_period:g} s: empty until then'
           if plot_period else '')]
    return '\n'.join(lines)


def legend_document(parameters, impulse_seconds, plot_period):
    """rr.TextDocument of the legend (Markdown)."""
    return rr.TextDocument(legend_text(parameters, impulse_seconds, plot_period),
                           media_type=rr.MediaType.MARKDOWN)
