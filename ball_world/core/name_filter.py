"""Entity-name filters matched by an automaton, so that no filter can stall the world.

Why: the standard's EntityFilters.filter is a regular expression from any client, and a
backtracking matcher (Python's re) takes exponential time on filters such as (a+)+$ or
.*.*.*x; a screen for such filters cannot be complete (an atomic group hides the nesting).
Here a filter is read by Python's own regular-expression parser, built into a Thompson NFA
(repetitions counted out, at most MAX_STATES states) and run as a DFA built lazily: each
character of a name costs one dictionary lookup, or, the first time a transition is met, one
pass over the NFA's states. Every pass is charged to a work budget (MAX_WORK), so even a
filter whose DFA is huge ends in bounded time: refused, never hanging.

The syntax is POSIX extended: literals, ., classes, \\d \\w \\s, groups, |, * + ? {m,n} (lazy
or greedy alike: only whether a name matches counts), ^ and $. What only a backtracking
matcher can mean (back references, look-arounds, atomic groups, possessive repeats, \\b) and
inline flags are refused with a reason. A filter matches a name when it matches anywhere in
it (re.search), as before.
"""
from re import _constants as sre  # what sre_constants became (3.11+)
from re import _parser as sre_parse  # what sre_parse became (3.11+)

#: Longest filter accepted, characters.
MAX_FILTER_LENGTH = 256
#: Most NFA states a filter may need once its repetitions are counted out.
MAX_STATES = 4096
#: Most DFA states kept; past it the cache starts again (correct, only slower).
MAX_DFA_STATES = 2048
#: Work units (NFA states visited while building transitions) one filter may spend in all:
#: a few seconds of Python at most.
MAX_WORK = 20_000_000

_CHAR, _SPLIT, _BEGIN, _END, _MATCH = range(5)
_ALLOWED_FLAGS = sre.SRE_FLAG_UNICODE | sre.SRE_FLAG_VERBOSE
_BEGINNINGS = (sre.AT_BEGINNING, sre.AT_BEGINNING_STRING)
_ENDS = (sre.AT_END, sre.AT_END_STRING)
_CATEGORIES = {
    sre.CATEGORY_DIGIT: str.isdecimal,
    sre.CATEGORY_NOT_DIGIT: lambda c: not c.isdecimal(),
    sre.CATEGORY_SPACE: str.isspace,
    sre.CATEGORY_NOT_SPACE: lambda c: not c.isspace(),
    sre.CATEGORY_WORD: lambda c: c.isalnum() or c == '_',
    sre.CATEGORY_NOT_WORD: lambda c: not (c.isalnum() or c == '_'),
}


class FilterRefused(ValueError):
    """A filter that is not accepted, or that spent its work budget; the message says why."""


def _class_test(items):
    """The test of one [...] class (items as sre_parse gives them)."""
    negate = bool(items) and items[0][0] == sre.NEGATE
    literals = set()
    ranges = []
    tests = []
    for op, argument in items[1:] if negate else items:
        if op == sre.LITERAL:
            literals.add(chr(argument))
        elif op == sre.RANGE:
            ranges.append(argument)
        elif op == sre.CATEGORY and argument in _CATEGORIES:
            tests.append(_CATEGORIES[argument])
        else:
            raise FilterRefused(f'{op} is not accepted in a character class')

    def test(c):
        inside = c in literals or any(low <= ord(c) <= high for low, high in ranges) \
            or any(t(c) for t in tests)
        return inside != negate
    return test


class _Builder:
    """Builds the NFA backwards: each piece is given the state that follows it."""

    def __init__(self):
        self.kinds = []
        self.tests = []
        self.outs = []
        self.spent = 0

    def add(self, kind, outs, test=None):
        self.spend()
        self.kinds.append(kind)
        self.tests.append(test)
        self.outs.append(list(outs))
        return len(self.kinds) - 1

    def spend(self):
        self.spent += 1
        if self.spent > MAX_STATES:
            raise FilterRefused(f'the filter needs more than {MAX_STATES:,} states once its '
                                'repetitions are counted out')

    def sequence(self, items, following):
        for op, argument in reversed(list(items)):
            following = self.item(op, argument, following)
        return following

    def item(self, op, argument, following):
        if op == sre.LITERAL:
            char = chr(argument)
            return self.add(_CHAR, [following], char.__eq__)
        if op == sre.NOT_LITERAL:
            char = chr(argument)
            return self.add(_CHAR, [following], char.__ne__)
        if op == sre.ANY:
            return self.add(_CHAR, [following], '\n'.__ne__)
        if op == sre.IN:
            return self.add(_CHAR, [following], _class_test(argument))
        if op == sre.SUBPATTERN:
            _, added, removed, items = argument
            if added & ~_ALLOWED_FLAGS or removed & ~_ALLOWED_FLAGS:
                raise FilterRefused('inline flags such as (?i) are not accepted')
            return self.sequence(items, following)
        if op == sre.BRANCH:
            return self.add(_SPLIT, [self.sequence(b, following) for b in argument[1]])
        if op in (sre.MAX_REPEAT, sre.MIN_REPEAT):
            return self.repeat(*argument, following)
        if op == sre.AT and argument in _BEGINNINGS:
            return self.add(_BEGIN, [following])
        if op == sre.AT and argument in _ENDS:
            return self.add(_END, [following])
        what = {sre.GROUPREF: 'back references', sre.GROUPREF_EXISTS: 'back references',
                sre.ASSERT: 'look-arounds', sre.ASSERT_NOT: 'look-arounds',
                sre.ATOMIC_GROUP: 'atomic groups', sre.POSSESSIVE_REPEAT: 'possessive repeats',
                sre.AT: 'word boundaries'}.get(op, str(op))
        raise FilterRefused(f'{what} are not accepted: filters are POSIX extended regular '
                            'expressions')

    def repeat(self, low, high, items, following):
        if high == sre.MAXREPEAT:
            loop = self.add(_SPLIT, [])
            self.outs[loop] = [self.sequence(items, loop), following]
            start = loop
        else:
            start = following
            for _ in range(high - low):  # each optional copy may stop at `following`
                start = self.add(_SPLIT, [self.sequence(items, start), following])
        for _ in range(low):
            self.spend()  # an empty group repeated a billion times costs its count
            start = self.sequence(items, start)
        return start


class NameFilter:
    """A compiled filter: search(name) says whether it matches anywhere in the name."""

    def __init__(self, pattern):
        if len(pattern) > MAX_FILTER_LENGTH:
            raise FilterRefused(f'the filter is {len(pattern):,} characters; at most '
                                f'{MAX_FILTER_LENGTH} are accepted')
        try:
            parsed = sre_parse.parse(pattern)
        except (sre.error, RecursionError, OverflowError, ValueError) as error:
            raise FilterRefused(f'the filter is not a regular expression: '
                                f'{str(error)[:120]}') from None
        if parsed.state.flags & ~_ALLOWED_FLAGS:
            raise FilterRefused('inline flags such as (?i) are not accepted')
        builder = _Builder()
        match = builder.add(_MATCH, [])
        self._start = builder.sequence(parsed, match)
        self._kinds, self._tests, self._outs = builder.kinds, builder.tests, builder.outs
        self.work = 0
        self._clear()

    def _clear(self):
        self._ids = {}
        self._sets = []
        self._matched = []
        self._at_end = []
        self._next = []
        self._initial = self._state(self._closure([self._start], True))

    def _closure(self, seeds, at_begin, at_end=False):
        """The states reachable from seeds without reading a character."""
        kinds, outs = self._kinds, self._outs
        seen = set()
        stack = list(seeds)
        found = []
        while stack:
            state = stack.pop()
            if state in seen:
                continue
            seen.add(state)
            kind = kinds[state]
            if kind == _SPLIT or (kind == _BEGIN and at_begin) or (kind == _END and at_end):
                stack.extend(outs[state])
            elif kind != _BEGIN:
                found.append(state)  # characters, the match, and $ still to be passed
        self._charge(len(seen))
        return frozenset(found)

    def _charge(self, units):
        self.work += units
        if self.work > MAX_WORK:
            raise FilterRefused('the filter is too costly to match against these names; '
                                'make it simpler')

    def _state(self, states):
        """The index of the DFA state made of these NFA states, added if new."""
        known = self._ids.get(states)
        if known is not None:
            return known
        index = len(self._sets)
        self._ids[states] = index
        self._sets.append(states)
        self._matched.append(any(self._kinds[s] == _MATCH for s in states))
        ends = [s for s in states if self._kinds[s] == _END]
        self._at_end.append(bool(ends) and any(
            self._kinds[s] == _MATCH for s in self._closure(ends, False, True)))
        self._next.append({})
        return index

    def _step(self, index, char):
        """The DFA state after reading `char` in state `index` (anywhere but the start)."""
        states = self._sets[index]
        moved = [self._outs[s][0] for s in states
                 if self._kinds[s] == _CHAR and self._tests[s](char)]
        self._charge(len(states))
        target = self._closure(moved + [self._start], False)
        if target not in self._ids and len(self._sets) >= MAX_DFA_STATES:
            self._clear()  # `index` is gone with the cache: this transition is not kept
            return self._state(target)
        following = self._state(target)
        self._next[index][char] = following
        return following

    def search(self, name):
        """Whether the filter matches somewhere in `name` (raises FilterRefused past MAX_WORK)."""
        if not name:
            return any(self._kinds[s] == _MATCH
                       for s in self._closure([self._start], True, True))
        state = self._initial
        if self._matched[state]:
            return True
        for char in name:
            following = self._next[state].get(char)
            state = self._step(state, char) if following is None else following
            if self._matched[state]:
                return True
        return self._at_end[state]
