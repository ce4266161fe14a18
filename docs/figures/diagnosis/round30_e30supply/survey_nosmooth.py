"""naming_survey.py with the branch's smooth current table switched off (the 'before' of this branch)."""
import sys
sys.path.insert(0, "scripts")
from etb_gym.diagnose import shapes as S
from etb_gym.diagnose import family_table as FT
_orig = S.family_terms
def family_terms(cid, base, data):
    return [t for t in _orig(cid, base, data) if t.coef_grid is None]
S.family_terms = family_terms
FT.family_terms = family_terms
import naming_survey
sys.exit(naming_survey.main(sys.argv[1:]))
