"""Wire models shared by the service and the client (pydantic v2; numpy + pydantic only)."""

from drape.schemas.catalog import BodyInfo, BodyList, Health, MotionInfo, MotionList

# a successful answer's warnings (done as asked, but something looks wrong): a JSON array of sentences, ASCII
# (drape.service.notices sets it; the client raises each as a drape.client.DrapeWarning)
WARNINGS_HEADER = "Drape-Warnings"

__all__ = ["WARNINGS_HEADER", "BodyInfo", "BodyList", "Health", "MotionInfo", "MotionList"]
