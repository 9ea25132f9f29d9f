"""What ball_world_score prints: its report (a plain dict, also its --json) as lines.

Pure formatting: the command line builds the dict and prints these lines.
"""
import math

#: Headline figures of a benchmark's table, with how they are shown.
BENCH_TRACKS = ('HOTA', 'DetA', 'AssA', 'LocA', 'IDF1', 'MOTA', 'MOTP', 'IDSW', 'CLR_FN',
                'CLR_FP')
BENCH_DETECTIONS = ('DetA', 'DetRe', 'DetPr', 'LocA', 'MODA', 'MODP', 'Recall', 'Precision')
NAMES = {'CLR_FN': 'misses', 'CLR_FP': 'false positives', 'IDSW': 'id switches',
         'DET_FN': 'misses', 'DET_FP': 'false positives'}


def _f(value, digits=4):
    return 'n/a' if value is None or (isinstance(value, float) and math.isnan(value)) \
        else f'{value:.{digits}f}'


def _n(value):
    return 'n/a' if value is None else f'{int(value):,}'


def figure_lines(figures, kind):
    """The headline figures of one score (a dict of figures.SequenceScore.figures())."""
    f = figures
    distance = f.get('mean_distance_m')
    metres = 'n/a' if distance is None or math.isnan(distance) else f'{distance:.3f} m'
    if kind == 'detections':
        return [
            f"DetA {_f(f['DetA'])}  (DetRe {_f(f['DetRe'])}, DetPr {_f(f['DetPr'])}, "
            f"LocA {_f(f['LocA'])})",
            f"MODA {_f(f['MODA'])}  MODP {_f(f['MODP'])} (mean distance {metres})",
            f"recall {_f(f['Recall'])}, precision {_f(f['Precision'])}, F1 {_f(f['F1'])}",
            f"matches {_n(f['DET_TP'])}, misses {_n(f['DET_FN'])}, false positives "
            f"{_n(f['DET_FP'])}"]
    return [
        f"HOTA {_f(f['HOTA'])}  (DetA {_f(f['DetA'])}, AssA {_f(f['AssA'])}, "
        f"LocA {_f(f['LocA'])})",
        f"IDF1 {_f(f['IDF1'])}  (IDP {_f(f['IDP'])}, IDR {_f(f['IDR'])})",
        f"MOTA {_f(f['MOTA'])}  MOTP {_f(f['MOTP'])} (mean distance {metres})",
        f"matches {_n(f['CLR_TP'])}, misses {_n(f['CLR_FN'])}, false positives "
        f"{_n(f['CLR_FP'])}, id switches {_n(f['IDSW'])}, fragmentations {_n(f['Frag'])}",
        f"balls mostly tracked {_n(f['MT'])}, partly tracked {_n(f['PT'])}, mostly lost "
        f"{_n(f['ML'])}"]


def recording_lines(report):
    """The report of one recording scored."""
    tracks = report['tracks']
    segments = report['segments']
    lines = [f"{report['recording']}: {_n(report['scans'])} scans of {report['agent']} "
             f"({segments} segment{'s' if segments != 1 else ''}), tracks of "
             f"{tracks['source']}, gate {report['gate']:g} m"]
    if tracks['kind'] == 'detections':
        lines.append(f"{tracks['type']} has no track ids: scored as detections, frame by "
                     'frame (no identity metrics: publish a MarkerArray, one marker id per '
                     'track, for IDF1, HOTA, MOTA)')
    truth = report['truth']
    lines.append(f"ground truth: {_n(truth['visible'])} ball sightings the scans could make "
                 f"({_n(truth['hidden'])} hidden: not scored); {_n(report['dont_care'])} "
                 "tracks on hidden balls are don't-care")
    stamps = report.get('stamps')
    if stamps and stamps.get('note'):
        lines.append(f"warning: {stamps['note']}")
    if stamps and stamps['scans_without_tracks']:
        lines.append(f"{_n(stamps['scans_without_tracks'])} of {_n(report['scans'])} scans "
                     'had no track message (scored as scans with no tracks)')
    lines += figure_lines(report['figures'], tracks['kind'])
    if report.get('per_ball') is not None:
        lines += breakdown_lines(report['per_ball'], report['per_track'])
    return lines


def breakdown_lines(balls, tracks):
    """The per-ball and per-track tables."""
    lines = ['', 'per ball: visible scans, tracked share, id switches, fragmentations, '
             'tracks that followed it',
             f"{'ball':<14} {'visible':>7} {'tracked':>7} {'switches':>8} {'frags':>5}  tracks"]
    for row in balls:
        lines.append(f"{str(row['ball']):<14} {row['frames']:>7} {row['tracked']:>7.1%} "
                     f"{row['switches']:>8} {row['fragmentations']:>5}  "
                     f"{' '.join(map(str, row['tracks'])) or '-'}")
    lines += ['', 'per track: first stamp and lifetime (s), scans, matched, false positive, '
              'switches, fragmentations, balls it followed',
              f"{'track':<14} {'first_s':>9} {'life_s':>7} {'scans':>6} {'matched':>7} "
              f"{'fp':>5} {'switches':>8} {'frags':>5}  balls"]
    for row in tracks:
        lines.append(f"{str(row['track']):<14} {row['first_s']:>9.3f} "
                     f"{row['lifetime_s']:>7.3f} {row['frames']:>6} {row['matched']:>7} "
                     f"{row['false_positives']:>5} {row['switches']:>8} "
                     f"{row['fragmentations']:>5}  {' '.join(map(str, row['balls'])) or '-'}")
    return lines


def bench_lines(report):
    """The report of a benchmark over scenes: each figure's mean and 95% interval."""
    kind = report['kind']
    lines = [f"{report['scenes']} scenes ({report['what']}), {report['tracker']}, gate "
             f"{report['gate']:g} m, {report['jobs']} processes, {report['seconds']:.1f} s",
             f"{'figure':<16} {'mean':>8} {'95% CI':>9} {'min':>8} {'max':>8}"]
    names = BENCH_TRACKS if kind == 'tracks' else BENCH_DETECTIONS
    for name in names:
        row = report['summary'][name]
        digits = 1 if name in NAMES else 4  # counts per scene
        ci = '' if row['ci95'] is None else f"+-{row['ci95']:.{digits}f}"
        lines.append(f"{NAMES.get(name, name):<16} {_f(row['mean'], digits):>8} {ci:>9} "
                     f"{_f(row['min'], digits):>8} {_f(row['max'], digits):>8}")
    pooled = report.get('pooled')
    if pooled:
        lines += ['', 'all scenes pooled (as TrackEval combines sequences):']
        lines += figure_lines(pooled, kind)
    for note in report.get('stamp_notes', ()):
        lines.append(f'warning: {note}')
    lines += ['', f"worst scenes by {report['worst_by']}: " + ', '.join(
        f'{label} ({_f(value)})' for label, value in report['worst'])]
    return lines
