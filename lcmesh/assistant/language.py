"""The operator's language: which of English, Spanish, German or French a question is in, and the words of each.

``detect_language(text)`` scores each language by the function words and plant words of the question
("¿cuál gabinete está más caliente?", "welcher Schrank ist am heißesten?", "quelle armoire est la plus
chaude ?") and by the letters only one of them writes (ñ ¿ ¡ á í ó ú; ä ö ü ß; è ê ç à â ô û œ; the
French elisions l' d' qu'). A word two languages share counts half for each. The answer is English
unless another language leads by at least a word: a short or ambiguous question ("status", "PUE?",
"cdu 3") is English. No dependency and no model file: py3langid (langid.py's maintained fork) did no
better on the same short questions (docs/ui.md "Languages").

The catalog below is every fixed word of the assistant's answers in the four languages: phrases
(``PHRASES``, filled by ``writer.py``), quantity labels with their article (``LABELS``; English ones
are ``plant_data.QUANTITIES``'s), entity names (``ENTITY_FORMS``), superlatives and folds. Templates
hold no digits: numbers come from facts, with "." as the decimal separator in every language.
"""

from __future__ import annotations

import re
from typing import Literal

Language = Literal["en", "es", "de", "fr"]
LANGUAGES: tuple[Language, ...] = ("en", "es", "de", "fr")

_WORDS: dict[str, str] = {
    "en": "the a an what what's which who how much many is are was were be do does did of in on at to for from by "
          "with and or now right current currently show tell me give list any all why when where since ago last "
          "over past hour hours minutes minute if would could should i we our you it its this that there "
          "hottest coolest warmest highest lowest most least average mean temperature power pump pumps fan fans "
          "tower towers cabinet cabinets branch branches supply return setpoint setpoints flow heat load band "
          "outside inside raise lower set increase decrease compare alerts alert controller running status "
          "plant blade blades wet bulb approach rejected versus vs happen happens up down between "
          "active open please can running switch much",
    "es": "el la los las lo un una unos unas de del al en y o que qué cuál cuáles cual cuales cuánto cuánta cuántos "
          "cuántas cuanto cuanta cuantos cuantas cómo como por para es son está están esta estan hay ha han fue "
          "me se si sí con sin desde hace entre sobre ahora actual actualmente último última últimos últimas "
          "ultimo ultima ultimos ultimas hola gracias hora horas minutos minuto más mas menos caliente calientes "
          "frío fría frio fria alto alta bajo baja máximo mínimo promedio media temperatura temperaturas potencia "
          "bomba bombas ventilador ventiladores gabinete gabinetes armario armarios rama ramas torre torres consigna "
          "impulsión impulsion suministro retorno caudal calor carga banda fuera dentro alertas alerta "
          "controlador regulador planta agua salida bulbo húmedo humedo aproximación subo bajo subir bajar "
          "sube baja pasaría pasa qué compara comparar muestra muéstrame dime dame estado cuál por qué porqué "
          "funciona funcionando activo activas activos todos todas hoy ayer",
    "de": "der die das den dem des ein eine einen einem einer ist sind war wie was welcher welche welches welchen "
          "wieviel viel viele warum wann wo im in an von vom zu zum zur und oder mit auf für über bei nach seit "
          "jetzt aktuell aktuelle aktuellen gerade letzten letzte letzter stunde stunden minuten es gibt mir "
          "zeige zeig sag nicht kein keine alle heißeste heißesten heisseste wärmste höchste höchsten "
          "niedrigste niedrigsten kälteste kältesten kühlste am durchschnitt durchschnittliche mittlere "
          "temperatur temperaturen leistung pumpe pumpen lüfter luefter turm türme zweig zweige strang schrank "
          "schränke sollwert vorlauf vorlauftemperatur rücklauf ruecklauf durchfluss wärme last band außerhalb "
          "innerhalb alarme alarm warnungen meldungen regler steuerung läuft anlage feuchtkugel feuchtkugeltemperatur "
          "erhöhe erhöhen senke senken wäre würde wenn passiert vergleiche vergleich aktiv aktive derzeit "
          "momentan heute gestern laufen läuft agenten zustand schalte um insgesamt gesamt hallo danke bitte",
    "fr": "le la les l un une des du de d au aux est sont était quel quelle quels quelles qu que quoi combien "
          "comment pourquoi quand où et ou en dans sur pour par avec sans il y a ce cette ces depuis "
          "maintenant actuel actuelle actuellement dernière dernières dernier derniers heure heures minutes "
          "plus moins chaud chaude chaudes froid froide élevé élevée élevés haut bas basse moyenne moyen "
          "température températures puissance pompe pompes ventilateur ventilateurs armoire armoires branche "
          "tour tours consigne départ retour débit chaleur charge bande hors alertes alerte contrôleur "
          "régulateur installation eau sortie bulbe humide approche augmente augmenter baisse baisser "
          "monte passerait arriverait compare comparer montre montre-moi donne dis état qui ne pas aucune "
          "toutes tous fonctionne actives actifs aujourd hui hier bonjour salut merci",
}
_VOCAB: dict[str, set[str]] = {lang: set(words.split()) for lang, words in _WORDS.items()}
_OWNERS: dict[str, tuple[str, ...]] = {}
for _lang, _words in _VOCAB.items():
    for _word in _words:
        _OWNERS[_word] = _OWNERS.get(_word, ()) + (_lang,)
_LETTERS = {"es": "ñ¿¡áíóú", "de": "äöüß", "fr": "èêëçàâîïôûùœ"}  # é is written in Spanish and French alike
_ELISION = re.compile(r"\b(?:l|d|qu|j|n|c|s)'(?=[aeiouyhéèêàâîô])", re.IGNORECASE)  # l'armoire, qu'est-ce
_TOKEN = re.compile(r"[^\W\d_]+")
_GERMAN_COMPOUND = re.compile(r"(?:temperatur|leistung|sollwert|druck|lauf|wasser|fluss|drehzahl|gruppen|kugel)$")
MIN_SCORE = 1.0  # at least one word or letter of its own: "cdu 3", "PUE?" and "ok" stay English


def language_scores(text: str) -> dict[str, float]:
    """Each language's evidence in `text`: words (shared ones split between their languages) and letters."""
    text = text.lower().replace("’", "'")
    scores = dict.fromkeys(LANGUAGES, 0.0)
    for token in _TOKEN.findall(text):
        owners = _OWNERS.get(token, ())
        if not owners and _GERMAN_COMPOUND.search(token):  # Pumpenleistung, Austrittswassertemperatur
            owners = ("de",)
        for lang in owners:
            scores[lang] += 1.0 / len(owners)
    for lang, letters in _LETTERS.items():
        scores[lang] += min(2.0, sum(text.count(c) for c in letters))
    if "é" in text:
        scores["es"] += 0.5
        scores["fr"] += 0.5
    scores["fr"] += 1.0 * len(_ELISION.findall(text))
    return scores


def detect_language(text: str) -> Language:
    """"en", "es", "de" or "fr" for an operator's question; English unless another language clearly leads."""
    scores = language_scores(text)
    best = max(LANGUAGES, key=lambda lang: scores[lang])
    runner_up = max(scores[lang] for lang in LANGUAGES if lang != best)
    if best == "en" or scores[best] < MIN_SCORE or scores[best] - runner_up < 1.0:
        return "en"
    return best


# --- the words of each language: the catalog the answer writer (writer.py) fills ----------------------------------
# Templates hold no digits (numbers come from facts); slots are {name}. English labels come from
# plant_data.QUANTITIES; the others carry their article, whose gender the superlatives agree with.
def _by_lang(en: str, es: str, de: str, fr: str) -> dict[str, str]:
    return {"en": en, "es": es, "de": de, "fr": fr}


LABELS: dict[str, dict[str, str]] = {key: dict(zip(("es", "de", "fr"), words)) for key, words in {
    "blade_temp": ("la temperatura de los blades", "die Blade-Temperatur", "la température des lames"),
    "blade_temp_mean": ("la temperatura media de los blades", "die mittlere Blade-Temperatur",
                        "la température moyenne des lames"),
    "supply_temp": ("la temperatura de impulsión medida", "die gemessene CDU-Vorlauftemperatur",
                    "la température de départ mesurée"),
    "supply_setpoint": ("la consigna de impulsión", "der CDU-Vorlaufsollwert", "la consigne de départ"),
    "return_temp": ("la temperatura de retorno", "die CDU-Rücklauftemperatur", "la température de retour"),
    "dp": ("la presión diferencial secundaria", "der Sekundär-Differenzdruck",
           "la pression différentielle secondaire"),
    "dp_setpoint": ("la consigna de dp", "der dp-Sollwert", "la consigne de dp"),
    "flow": ("el caudal de refrigerante secundario", "der Sekundär-Kühlmitteldurchfluss",
             "le débit de fluide secondaire"),
    "valve": ("la fracción de válvula", "der Ventilanteil", "la fraction d'ouverture de vanne"),
    "pump_speed": ("la velocidad de la bomba de la CDU", "die CDU-Pumpendrehzahl", "la vitesse de pompe de la CDU"),
    "cdu_pump_power": ("la potencia de la bomba de la CDU", "die CDU-Pumpenleistung",
                       "la puissance de pompe de la CDU"),
    "it_power": ("la potencia IT", "die IT-Leistung", "la puissance IT"),
    "cdu_heat": ("el calor extraído en las CDU", "die an den CDUs abgeführte Wärme", "la chaleur évacuée aux CDU"),
    "leaving_water": ("la temperatura de agua de salida", "die Austrittswassertemperatur",
                      "la température d'eau de sortie"),
    "lw_setpoint": ("la consigna de agua de salida", "der Austrittswasser-Sollwert", "la consigne d'eau de sortie"),
    "approach": ("la aproximación", "der Approach", "l'approche"),
    "fan_speed": ("la velocidad de ventiladores", "die Lüfterdrehzahl", "la vitesse des ventilateurs"),
    "tower_power": ("la potencia de ventiladores", "die Lüfterleistung", "la puissance des ventilateurs"),
    "pump_power": ("la potencia total de bombas", "die gesamte Pumpenleistung", "la puissance totale des pompes"),
    "cooling_power": ("la potencia de refrigeración", "die Kühlleistung", "la puissance de refroidissement"),
    "heat_rejected": ("el calor rechazado por las torres", "die von den Türmen abgegebene Wärme",
                      "la chaleur rejetée par les tours"),
    "wet_bulb": ("la temperatura de bulbo húmedo exterior", "die Außen-Feuchtkugeltemperatur",
                 "la température de bulbe humide extérieure"),
    "htw_supply_temp": ("la temperatura de impulsión del agua caliente", "die Warmwasser-Vorlauftemperatur",
                        "la température de départ d'eau chaude"),
    "htw_return_temp": ("la temperatura de retorno del agua caliente", "die Warmwasser-Rücklauftemperatur",
                        "la température de retour d'eau chaude"),
    "in_band": ("la proporción de grupos de blades en banda", "der Anteil der Blade-Gruppen im Band",
                "la part des groupes de lames dans la bande"),
    "pue": ("el PUE de refrigeración", "der Kühl-PUE", "le PUE de refroidissement"),
}.items()}  # fmt: skip
_ARTICLES = {"es": {"el": "m", "la": "f"}, "de": {"der": "m", "die": "f", "das": "n"},
             "fr": {"le": "m", "la": "f", "l'": "f"}}  # French "l'" labels here are all feminine (l'approche)

# Entity names by kind: bare, with its article ("the"), after "of" and after "in"; a nested name
# ("branch 2 of cabinet 3") puts the outer entity in its "of" form.
ENTITY_FORMS: dict[str, dict[str, tuple[str, str, str, str]]] = {
    "en": {"cabinet": ("cabinet", "cabinet", "of cabinet", "in cabinet"),
           "branch": ("branch", "branch", "of branch", "in branch"),
           "tower": ("tower", "tower", "of tower", "in tower"),
           "blade group": ("blade group", "blade group", "of blade group", "in blade group")},
    "es": {"cabinet": ("gabinete", "el gabinete", "del gabinete", "en el gabinete"),
           "branch": ("rama", "la rama", "de la rama", "en la rama"),
           "tower": ("torre", "la torre", "de la torre", "en la torre"),
           "blade group": ("grupo de blades", "el grupo de blades", "del grupo de blades", "en el grupo de blades")},
    "de": {"cabinet": ("Schrank", "Schrank", "von Schrank", "in Schrank"),
           "branch": ("Zweig", "Zweig", "von Zweig", "in Zweig"),
           "tower": ("Turm", "Turm", "von Turm", "in Turm"),
           "blade group": ("Blade-Gruppe", "Blade-Gruppe", "von Blade-Gruppe", "in Blade-Gruppe")},
    "fr": {"cabinet": ("armoire", "l'armoire", "de l'armoire", "dans l'armoire"),
           "branch": ("branche", "la branche", "de la branche", "dans la branche"),
           "tower": ("tour", "la tour", "de la tour", "dans la tour"),
           "blade group": ("groupe de lames", "le groupe de lames", "du groupe de lames", "dans le groupe de lames")},
}  # fmt: skip

# "highest"/"lowest" agreeing with a label's gender (rank), and how the plant value folds (word, sentence head).
SUPERLATIVES = {"en": {"highest": {"": "highest"}, "lowest": {"": "lowest"}},
                "es": {"highest": {"m": "más alto", "f": "más alta"}, "lowest": {"m": "más bajo", "f": "más baja"}},
                "de": {"highest": {"": "höchsten"}, "lowest": {"": "niedrigsten"}},
                "fr": {"highest": {"m": "le plus élevé", "f": "la plus élevée"},
                       "lowest": {"m": "le plus bas", "f": "la plus basse"}}}  # fmt: skip
FOLDS = {"en": {"mean": ("mean", "The mean"), "sum": ("total", "The total"), "max": ("highest", "The highest"),
                "min": ("lowest", "The lowest")},
         "es": {"mean": ("media", "La media"), "sum": ("total", "El total"), "max": ("máximo", "El máximo"),
                "min": ("mínimo", "El mínimo")},
         "de": {"mean": ("Mittel", "Das Mittel"), "sum": ("Summe", "Die Summe"), "max": ("Maximum", "Das Maximum"),
                "min": ("Minimum", "Das Minimum")},
         "fr": {"mean": ("moyenne", "La moyenne"), "sum": ("total", "Le total"), "max": ("maximum", "Le maximum"),
                "min": ("minimum", "Le minimum")}}  # fmt: skip

_CAN_DO = _by_lang(
    "I can tell you any reading of a cabinet, branch or tower now; averages, peaks and changes over the last hours; "
    "rankings and side-by-side comparisons; how many blade groups are outside the band; PUE, approach and the heat "
    "balance; alerts; why the controller did something; which controller runs and since when; what a setpoint "
    "change would do; and I can propose a change for an operator to confirm.",
    "Puedo darle cualquier lectura de un gabinete, una rama o una torre ahora; medias, picos y cambios de las últimas "
    "horas; clasificaciones y comparaciones lado a lado; cuántos grupos de blades están fuera de la banda; el PUE, "
    "la aproximación y el balance de calor; alertas; por qué el controlador hizo algo; qué controlador funciona y "
    "desde cuándo; qué haría un cambio de consigna; y puedo proponer un cambio para que un operador lo confirme.",
    "Ich kann Ihnen jeden Messwert eines Schranks, Zweigs oder Turms nennen; Mittelwerte, Spitzen und Änderungen der "
    "letzten Stunden; Rangfolgen und Vergleiche; wie viele Blade-Gruppen außerhalb des Bandes liegen; PUE, Approach "
    "und Wärmebilanz; Alarme; warum der Regler etwas getan hat; welcher Regler läuft und seit wann; was eine "
    "Sollwertänderung bewirken würde; und ich kann eine Änderung vorschlagen, die ein Operator bestätigt.",
    "Je peux vous donner toute mesure d'une armoire, d'une branche ou d'une tour ; moyennes, pics et variations des "
    "dernières heures ; classements et comparaisons ; combien de groupes de lames sont hors de la bande ; PUE, "
    "approche et bilan thermique ; alertes ; pourquoi le régulateur a fait quelque chose ; quel régulateur tourne et "
    "depuis quand ; ce que ferait un changement de consigne ; et je peux proposer un changement qu'un opérateur "
    "confirmera.",
)  # fmt: skip
PHRASES: dict[str, dict[str, str]] = {
    "can_do": _CAN_DO,
    "refusal": _by_lang("I can't tell that from here. ", "No puedo saber eso desde aquí. ",
                        "Das kann ich von hier aus nicht sagen. ", "Je ne peux pas le dire d'ici. "),
    "decline": _by_lang("I can't answer that as asked: the question asks for {missing}, and what I found does not "
                        "give it.", "No puedo responder a eso tal como se preguntó: la pregunta pide {missing}, y lo "
                        "que encontré no lo da.", "Das kann ich so nicht beantworten: die Frage verlangt {missing}, "
                        "und was ich gefunden habe, liefert das nicht.", "Je ne peux pas répondre à cela tel quel : "
                        "la question demande {missing}, et ce que j'ai trouvé ne le donne pas."),
    "decline.instead": _by_lang("What I can give instead (not an answer to your question): {draft}",
                                "Lo que puedo dar en su lugar (no es la respuesta a su pregunta): {draft}",
                                "Was ich stattdessen geben kann (keine Antwort auf Ihre Frage): {draft}",
                                "Ce que je peux donner à la place (pas une réponse à votre question) : {draft}"),
    "tool_error": _by_lang("I can't answer that as asked: “{error}”.", "No puedo responder a eso tal como se "
                           "preguntó: “{error}”.", "Das kann ich so nicht beantworten: “{error}”.",
                           "Je ne peux pas répondre à cela tel quel : “{error}”."),
    # plant_state
    "state.plant": _by_lang("The {label} is {value}.", "{the_label} es {value}.", "{the_label} beträgt {value}.",
                            "{the_label} est de {value}."),
    "state.one": _by_lang("The {label} {entity_of} is {value}.", "{the_label} {entity_of} es {value}.",
                          "{the_label} {entity_in} beträgt {value}.", "{the_label} {entity_of} est de {value}."),
    "state.scope": _by_lang("The {label} {entity_in} ({fold}) is {value}: {items}.",
                            "{the_label} {entity_in} ({fold}) es {value}: {items}.",
                            "{the_label} {entity_in} ({fold}) beträgt {value}: {items}.",
                            "{the_label} {entity_in} ({fold}) est de {value} : {items}."),
    "state.all": _by_lang("The {label} is {value} ({fold} over the plant): {items}.",
                          "{the_label} es {value} ({fold} de la planta): {items}.",
                          "{the_label} beträgt {value} ({fold} über die Anlage): {items}.",
                          "{the_label} est de {value} ({fold} sur l'installation) : {items}."),
    "item": _by_lang("{entity} {value}", "{entity} {value}", "{entity} {value}", "{entity} {value}"),
    # overview
    "overview": _by_lang(
        "The hottest blade group is {entity_in} at {value}; {pct} of blade groups are inside the band. IT power {it}, "
        "tower fans {fans}, pumps {pumps}, wet bulb {wb}",
        "El grupo de blades más caliente está {entity_in} a {value}; el {pct} de los grupos de blades está dentro de "
        "la banda. Potencia IT {it}, ventiladores de las torres {fans}, bombas {pumps}, bulbo húmedo {wb}",
        "Die heißeste Blade-Gruppe liegt {entity_in} bei {value}; {pct} der Blade-Gruppen liegen innerhalb des "
        "Bandes. IT-Leistung {it}, Turmlüfter {fans}, Pumpen {pumps}, Feuchtkugel {wb}",
        "Le groupe de lames le plus chaud est {entity_in} à {value} ; {pct} des groupes de lames sont dans la "
        "bande. Puissance IT {it}, ventilateurs des tours {fans}, pompes {pumps}, bulbe humide {wb}"),
    "overview.pue": _by_lang(", cooling PUE {pue}", ", PUE de refrigeración {pue}", ", Kühl-PUE {pue}",
                             ", PUE de refroidissement {pue}"),
    "overview.controller": _by_lang(" The last action came from {controller}.", " La última acción vino de "
                                    "{controller}.", " Die letzte Aktion kam von {controller}.",
                                    " La dernière action vient de {controller}."),
    # history_stat
    "history.change": _by_lang("Over the last {minutes} the {label} {trend}, from {first} to {last}.",
                               "En los últimos {minutes}, {the_label} {trend}, de {first} a {last}.",
                               "In den letzten {minutes} ist {the_label} {trend}, von {first} auf {last}.",
                               "Sur les dernières {minutes}, {the_label} {trend}, passant de {first} à {last}."),
    "trend.up": _by_lang("went up {change}", "subió {change}", "um {change} gestiegen", "a augmenté de {change}"),
    "trend.down": _by_lang("went down {change}", "bajó {change}", "um {change} gesunken", "a baissé de {change}"),
    "trend.flat": _by_lang("went unchanged {change}", "no cambió ({change})", "gleich geblieben ({change})",
                           "n'a pas changé ({change})"),
    "history.stat": _by_lang("Over the last {minutes} the {label} {word} {value} (range {min} to {max}; now {last}).",
                             "En los últimos {minutes}, {the_label} {word} {value} (rango de {min} a {max}; ahora "
                             "{last}).", "In den letzten {minutes} lag {the_label} {word} {value} (Bereich {min} bis "
                             "{max}; jetzt {last}).", "Sur les dernières {minutes}, {the_label} {word} {value} (plage "
                             "de {min} à {max} ; maintenant {last})."),
    "stat.mean": _by_lang("averaged", "promedió", "im Mittel bei", "a été en moyenne de"),
    "stat.max": _by_lang("peaked at", "alcanzó un máximo de", "in der Spitze bei", "a culminé à"),
    "stat.min": _by_lang("was lowest at", "tuvo un mínimo de", "im Minimum bei", "a été au plus bas à"),
    "history.short": _by_lang(" History of this run reaches back only that far, not the {asked} asked.",
                              " El historial de esta ejecución no llega más atrás, no a los {asked} pedidos.",
                              " Die Historie dieses Laufs reicht nur so weit zurück, nicht die gefragten {asked}.",
                              " L'historique de cette exécution ne remonte pas plus loin, pas aux {asked} "
                              "demandées."),
    # rank
    "rank.first": _by_lang("{entity} has the {order} {label}: {value}.", "{entity_the} tiene {the_label} {order}: "
                           "{value}.", "Den {order} Wert ({label}) hat {entity}: {value}.",
                           "{entity_the} a {the_label} {order} : {value}."),
    "rank.next": _by_lang(" Next: {items}.", " Siguen: {items}.", " Danach: {items}.", " Ensuite : {items}."),
    "rank.plant": _by_lang(" The {fold} over all {count} is {value}.", " {fold_head} de los {count} es {value}.",
                           " {fold_head} über alle {count} beträgt {value}.",
                           " {fold_head} sur les {count} est de {value}."),
    # compare
    "compare.equal": _by_lang("The {label}: {items}. They are equal at the displayed precision.",
                              "{the_label}: {items}. Son iguales a la precisión mostrada.",
                              "{the_label}: {items}. Bei der angezeigten Genauigkeit sind sie gleich.",
                              "{the_label} : {items}. Ils sont égaux à la précision affichée."),
    "compare": _by_lang("The {label}: {items}. {highest_cap} is the highest, {diff} above {lowest}.",
                        "{the_label}: {items}. El valor más alto lo tiene {highest_the}, {diff} por encima "
                        "{lowest_of}.", "{the_label}: {items}. Den höchsten Wert hat {highest}, {diff} über {lowest}.",
                        "{the_label} : {items}. La valeur la plus élevée est celle {highest_of}, {diff} au-dessus "
                        "{lowest_of}."),
    # band_count
    "band": _by_lang("{inside} of {total} blade groups are inside the {low} to {high} band ({pct}); {above} above, "
                     "{below} below.", "{inside} de {total} grupos de blades están dentro de la banda de {low} a "
                     "{high} ({pct}); {above} por encima, {below} por debajo.", "{inside} von {total} Blade-Gruppen "
                     "liegen innerhalb des Bandes von {low} bis {high} ({pct}); {above} darüber, {below} darunter.",
                     "{inside} sur {total} groupes de lames sont à l'intérieur de la bande de {low} à {high} ({pct}) "
                     "; {above} au-dessus, {below} en dessous."),
    "band.outside": _by_lang(" Outside: {items}.", " Fuera: {items}.", " Außerhalb: {items}.",
                             " Hors de la bande : {items}."),
    "band.item": _by_lang("{entity} at {value}", "{entity} a {value}", "{entity} mit {value}", "{entity} à {value}"),
    # energy_balance
    "energy": _by_lang("IT load {it}; the CDUs move {cdu} and the towers reject {rejected}",
                       "Carga IT {it}; las CDU extraen {cdu} y las torres rechazan {rejected}",
                       "IT-Last {it}; die CDUs führen {cdu} ab und die Türme geben {rejected} ab",
                       "Charge IT {it} ; les CDU évacuent {cdu} et les tours rejettent {rejected}"),
    "energy.share": _by_lang(" ({pct} of IT)", " ({pct} de la carga IT)", " ({pct} der IT-Last)",
                             " ({pct} de la charge IT)"),
    "energy.cooling": _by_lang(". Cooling takes {cooling}: tower fans {fans}, pumps {pumps}",
                               ". La refrigeración consume {cooling}: ventiladores de las torres {fans}, bombas "
                               "{pumps}", ". Die Kühlung braucht {cooling}: Turmlüfter {fans}, Pumpen {pumps}",
                               ". Le refroidissement consomme {cooling} : ventilateurs des tours {fans}, pompes "
                               "{pumps}"),
    "energy.pue": _by_lang("; cooling PUE {pue}", "; PUE de refrigeración {pue}", "; Kühl-PUE {pue}",
                           " ; PUE de refroidissement {pue}"),
    # alerts
    "alerts.none.active": _by_lang("No alerts are active ({count}).", "No hay alertas activas ({count}).",
                                   "Keine Alarme aktiv ({count}).", "Aucune alerte active ({count})."),
    "alerts.none.recorded": _by_lang("No alerts are recorded ({count}).", "No hay alertas registradas ({count}).",
                                     "Keine Alarme aufgezeichnet ({count}).", "Aucune alerte enregistrée ({count})."),
    "alerts.active": _by_lang("{count} alert(s) active: {items}.", "{count} alerta(s) activa(s): {items}.",
                              "{count} Alarm(e) aktiv: {items}.", "{count} alerte(s) active(s) : {items}."),
    "alerts.recorded": _by_lang("{count} alert(s) recorded: {items}.", "{count} alerta(s) registrada(s): {items}.",
                                "{count} Alarm(e) aufgezeichnet: {items}.",
                                "{count} alerte(s) enregistrée(s) : {items}."),
    "alert.where": _by_lang("at", "en", "bei", "à"),
    "alert.plant": _by_lang("the plant", "la planta", "der Anlage", "l'installation"),
    "alerts.advice": _by_lang(" Suggested: {quote}", " Sugerencia: {quote}", " Empfehlung: {quote}",
                              " Conseil : {quote}"),
    # decision
    "decision.none": _by_lang("No decision in the last {count} decisions matches that.",
                              "Ninguna de las últimas {count} decisiones coincide con eso.",
                              "Keine der letzten {count} Entscheidungen passt dazu.",
                              "Aucune des {count} dernières décisions ne correspond."),
    "decision": _by_lang("Decision {id} (step {step}, {controller}{fallback})",
                         "Decisión {id} (paso {step}, {controller}{fallback})",
                         "Entscheidung {id} (Schritt {step}, {controller}{fallback})",
                         "Décision {id} (étape {step}, {controller}{fallback})"),
    "decision.fallback": _by_lang(", a fallback", ", como respaldo", ", als Rückfallebene", ", en repli"),
    "decision.changes": _by_lang(": {items}.", ": {items}.", ": {items}.", " : {items}."),
    "decision.change": _by_lang("{trend} the {head} {entity_of} from {before} to {after}",
                                "{trend} {head} {entity_of} de {before} a {after}",
                                "{head} {entity_of} von {before} auf {after} {trend}",
                                "{trend} {head} {entity_of} de {before} à {after}"),
    "decision.nothing": _by_lang(" changed nothing beyond the dead bands.", " no cambió nada más allá de las bandas "
                                 "muertas.", " änderte nichts über die Totbänder hinaus.",
                                 " n'a rien changé au-delà des bandes mortes."),
    "decision.reasons": _by_lang(" Its reasons for {entity}, written by the toolbox from the decision's state (the "
                                 "published one is about another cabinet, or not out yet): {quote}",
                                 " Sus razones para {entity}, escritas por la caja de herramientas a partir del "
                                 "estado de la decisión (la publicada trata de otro gabinete, o aún no salió): {quote}",
                                 " Ihre Gründe für {entity}, vom Werkzeugkasten aus dem Zustand der Entscheidung "
                                 "geschrieben (die veröffentlichte betrifft einen anderen Schrank oder fehlt noch): {quote}",
                                 " Ses raisons pour {entity}, écrites par la boîte à outils à partir de l'état de la "
                                 "décision (celle publiée porte sur une autre armoire, ou n'est pas encore là) : {quote}"),
    "decision.explanation": _by_lang(" Its explanation: {quote}", " Su explicación: {quote}",
                                     " Ihre Erklärung: {quote}", " Son explication : {quote}"),
    "raised": _by_lang("raised", "subió", "erhöht", "a relevé"),
    "lowered": _by_lang("lowered", "bajó", "gesenkt", "a abaissé"),
    "opened": _by_lang("opened", "abrió", "geöffnet", "a ouvert"),
    "closed": _by_lang("closed", "cerró", "geschlossen", "a fermé"),
    "head.supply": _by_lang("supply setpoint", "la consigna de impulsión", "Vorlaufsollwert", "la consigne de départ"),
    "head.dp": _by_lang("dp setpoint", "la consigna de dp", "dp-Sollwert", "la consigne de dp"),
    "head.lw": _by_lang("leaving-water setpoint", "la consigna de agua de salida", "Austrittswasser-Sollwert",
                        "la consigne d'eau de sortie"),
    "head.valve": _by_lang("valve", "la válvula", "Ventil", "la vanne"),
    # controller
    "controller": _by_lang("The configured controller is {controller}", "El controlador configurado es {controller}",
                           "Der konfigurierte Regler ist {controller}", "Le régulateur configuré est {controller}"),
    "controller.mode": _by_lang(" in {mode} mode", " en modo {mode}", " im Modus {mode}", " en mode {mode}"),
    "controller.since": _by_lang(", since {since} (configuration version {version})",
                                 ", desde {since} (versión de configuración {version})",
                                 ", seit {since} (Konfigurationsversion {version})",
                                 ", depuis {since} (version de configuration {version})"),
    "controller.acting": _by_lang("The last applied action (step {step}) came from {controller}",
                                  "La última acción aplicada (paso {step}) vino de {controller}",
                                  "Die letzte angewandte Aktion (Schritt {step}) kam von {controller}",
                                  "La dernière action appliquée (étape {step}) vient de {controller}"),
    "controller.fallback": _by_lang(", as a fallback: {quote}", ", como respaldo: {quote}",
                                    ", als Rückfallebene: {quote}", ", en repli : {quote}"),
    # agents
    "agents": _by_lang("{alive} of {known} agents are alive.", "{alive} de {known} agentes están activos.",
                       "{alive} von {known} Agenten sind aktiv.", "{alive} agents sur {known} sont actifs."),
    "agents.down": _by_lang(" Down: {down}.", " Caídos: {down}.", " Ausgefallen: {down}.", " En panne : {down}."),
    "agents.advice": _by_lang(" Monitor: {quote}", " Monitor: {quote}", " Monitor: {quote}", " Moniteur : {quote}"),
    # propose_change
    "propose.quote": _by_lang("Proposed: {quote}.", "Propuesta: {quote}.", "Vorschlag: {quote}.",
                              "Proposition : {quote}."),
    "propose.set": _by_lang("Proposed: set the {label}{where} from {now} to {new}.",
                            "Propuesta: cambiar {the_label}{where} de {now} a {new}.",
                            "Vorschlag: {label}{where} von {now} auf {new} setzen.",
                            "Proposition : régler {the_label}{where} de {now} à {new}."),
    "propose.where": _by_lang(" {entity_of}", " {entity_of}", " {entity_of}", " {entity_of}"),
    "propose.problem": _by_lang(" This cannot be applied as asked: {quote}.", " No se puede aplicar tal como se "
                                "pidió: {quote}.", " So lässt es sich nicht anwenden: {quote}.",
                                " Impossible de l'appliquer tel quel : {quote}."),
    "propose.confirm": _by_lang(
        " Chat does not change the plant: an operator confirms by sending the proposed request with the API token.",
        " El chat no cambia la planta: un operador lo confirma enviando la solicitud propuesta con el token de la API.",
        " Der Chat ändert die Anlage nicht: Ein Operator bestätigt, indem er die vorgeschlagene Anfrage mit dem "
        "API-Token sendet.",
        " Le chat ne modifie pas l'installation : un opérateur confirme en envoyant la requête proposée avec le jeton "
        "d'API."),
    # whatif_setpoint
    "whatif": _by_lang(
        "Look-ahead of {minutes} on the live twin (load and weather held) for {verb} {scope} {label} by {change}. "
        "Predicted against holding the setpoints: hottest blade group {blade}; in band {band}; tower fans {fans}; "
        "pumps {pumps}. Nothing was changed.",
        "Previsión a {minutes} en el gemelo en vivo (carga y clima fijos) al {verb} {the_label}{scope} en {change}. "
        "Predicción frente a mantener las consignas: grupo de blades más caliente {blade}; en banda {band}; "
        "ventiladores de las torres {fans}; bombas {pumps}. No se cambió nada.",
        "Vorausschau über {minutes} am Live-Zwilling (Last und Wetter gehalten): {label}{scope} um {change} {verb}. "
        "Vorhersage gegenüber gehaltenen Sollwerten: heißeste Blade-Gruppe {blade}; im Band {band}; Turmlüfter "
        "{fans}; Pumpen {pumps}. Nichts wurde geändert.",
        "Prévision à {minutes} sur le jumeau en direct (charge et météo fixes) pour {verb} {the_label}{scope} de "
        "{change}. Prévu par rapport au maintien des consignes : groupe de lames le plus chaud {blade} ; dans la "
        "bande {band} ; ventilateurs des tours {fans} ; pompes {pumps}. Rien n'a été modifié."),
    # energy_used
    "energy_used": _by_lang(
        "Over the last {minutes} the {what} used {kwh} of energy (on average {mean} of power).",
        "En los últimos {minutes}, {what} consumió {kwh} de energía (potencia media {mean}).",
        "In den letzten {minutes} hat {what} {kwh} Energie verbraucht (mittlere Leistung {mean}).",
        "Sur les dernières {minutes}, {what} a consommé {kwh} d'énergie (puissance moyenne {mean})."),
    "energy_used.what.cooling": _by_lang("cooling plant", "la refrigeración", "die Kühlung", "le refroidissement"),
    "energy_used.what.pumps": _by_lang("pumps", "el conjunto de bombas", "der Pumpenpark", "l'ensemble des pompes"),
    "energy_used.what.tower_fans": _by_lang("tower fans", "el conjunto de ventiladores de las torres",
                                            "der Turmlüfterpark", "l'ensemble des ventilateurs des tours"),
    "energy_used.what.it": _by_lang("IT load", "la carga IT", "die IT-Last", "la charge IT"),
    "energy_used.what.heat_rejected": _by_lang("heat rejected by the towers (heat, not power drawn)",
                                               "el calor rechazado por las torres (calor, no consumo)",
                                               "die von den Türmen abgegebene Wärme (Wärme, kein Verbrauch)",
                                               "la chaleur rejetée par les tours (chaleur, pas consommation)"),
    # tracking_gap
    "gap.cabinet": _by_lang("Measured CDU supply against its setpoint: {items}.",
                            "Impulsión medida de cada CDU frente a su consigna: {items}.",
                            "Gemessener CDU-Vorlauf gegen seinen Sollwert: {items}.",
                            "Départ CDU mesuré face à sa consigne : {items}."),
    "gap.tower": _by_lang("Tower leaving water against its setpoint: {items}.",
                          "Agua de salida de cada torre frente a su consigna: {items}.",
                          "Turm-Austrittswasser gegen seinen Sollwert: {items}.",
                          "Eau de sortie des tours face à sa consigne : {items}."),
    "gap.item": _by_lang("{entity} {gap} {side} ({measured} against {setpoint})",
                         "{entity} {gap} {side} ({measured} frente a {setpoint})",
                         "{entity} {gap} {side} ({measured} gegen {setpoint})",
                         "{entity} {gap} {side} ({measured} face à {setpoint})"),
    "gap.above": _by_lang("above", "por encima", "darüber", "au-dessus"),
    "gap.below": _by_lang("below", "por debajo", "darunter", "en dessous"),
    "gap.largest": _by_lang(" The biggest gap: {entity}.", " La mayor diferencia: {entity}.",
                            " Die größte Abweichung: {entity}.", " Le plus grand écart : {entity}."),
    # peak
    "peak": _by_lang("Over the last {minutes}, the {label} {word} {value} {entity_in}, at {at} ({ago} ago).",
                     "En los últimos {minutes}, {the_label} {word} {value} {entity_in}, a las {at} (hace {ago}).",
                     "{the_label} lag {word} {value} {entity_in}, um {at} (vor {ago}), gesehen über die letzten "
                     "{minutes}.",
                     "Sur les dernières {minutes}, {the_label} {word} {value} {entity_in}, à {at} (il y a {ago})."),
    "peak.plant": _by_lang("Over the last {minutes} the {label} {word} {value} at {at} ({ago} ago).",
                           "En los últimos {minutes}, {the_label} {word} {value} a las {at} (hace {ago}).",
                           "In den letzten {minutes} lag {the_label} {word} {value} um {at} (vor {ago}).",
                           "Sur les dernières {minutes}, {the_label} {word} {value} à {at} (il y a {ago})."),
    # weather_effect
    "weather": _by_lang(
        "The wet bulb is {wb} ({wb_change} over the last {minutes}); the tower fans draw {fans} ({fans_change} over "
        "the same time). Per tower: {items}.",
        "El bulbo húmedo está en {wb} ({wb_change} en los últimos {minutes}); los ventiladores de las torres consumen "
        "{fans} ({fans_change} en ese tiempo). Por torre: {items}.",
        "Die Feuchtkugel liegt bei {wb} ({wb_change} in den letzten {minutes}); die Turmlüfter ziehen {fans} "
        "({fans_change} in derselben Zeit). Je Turm: {items}.",
        "Le bulbe humide est à {wb} ({wb_change} sur les dernières {minutes}) ; les ventilateurs des tours consomment "
        "{fans} ({fans_change} sur la même période). Par tour : {items}."),
    "weather.item": _by_lang("{entity} has approach {approach} and leaving water {lw} with fan speed {speed} and fan "
                             "power {power}", "{entity} tiene aproximación {approach} y agua de salida {lw} con "
                             "velocidad de ventiladores {speed} y ventiladores {power}", "{entity} hat Approach "
                             "{approach} und Austrittswasser {lw} bei Lüfterdrehzahl {speed} und Lüfterleistung "
                             "{power}", "{entity} a une approche de {approach} et une eau de sortie à {lw} avec une "
                             "vitesse des ventilateurs de {speed} et des ventilateurs à {power}"),
    "weather.per_k": _by_lang(" At this load the tower fans would need about {per_k} more to hold the same leaving "
                              "water at one more kelvin of wet bulb (tower model).",
                              " Con esta carga, los ventiladores necesitarían unos {per_k} más para mantener la "
                              "misma agua de salida con un kelvin más de bulbo húmedo (modelo de torre).",
                              " Bei dieser Last bräuchten die Lüfter etwa {per_k} mehr, um dasselbe "
                              "Austrittswasser bei einem Kelvin mehr Feuchtkugel zu halten (Turmmodell).",
                              " À cette charge, les ventilateurs auraient besoin d'environ {per_k} de plus pour "
                              "garder la même eau de sortie avec un kelvin de bulbe humide en plus (modèle de tour)."),
    "weather.per_k.none": _by_lang(" At one more kelvin of wet bulb a tower could not hold today's leaving water even "
                                   "at full fan speed.", " Con un kelvin más de bulbo húmedo, una torre no podría "
                                   "mantener el agua de salida actual ni a plena velocidad.", " Bei einem Kelvin "
                                   "mehr Feuchtkugel könnte ein Turm das heutige Austrittswasser selbst mit voller "
                                   "Lüfterdrehzahl nicht halten.", " Avec un kelvin de bulbe humide en plus, une "
                                   "tour ne pourrait pas tenir l'eau de sortie actuelle même à pleine vitesse."),
    "trend.signed.up": _by_lang("up {change}", "sube {change}", "plus {change}", "en hausse de {change}"),
    "trend.signed.down": _by_lang("down {change}", "baja {change}", "minus {change}", "en baisse de {change}"),
    "trend.signed.flat": _by_lang("unchanged", "sin cambio", "unverändert", "inchangé"),
    # whatif_controller
    "whatif_ctrl": _by_lang(
        "A look-ahead of {minutes} on the live twin (load and weather held), from the state now: {current} would "
        "use {cur_kwh} of cooling energy (hottest blade group {cur_hot}; in band on average {cur_band}); {other} "
        "{alt_kwh} (hottest blade group {alt_hot}; in band {alt_band}). {verdict} Nothing was changed.",
        "Simulación de {minutes} en el gemelo en vivo (carga y clima fijos), desde el estado actual: {current} "
        "usaría {cur_kwh} de energía de refrigeración (grupo de blades más caliente {cur_hot}; en banda de media "
        "{cur_band}); {other} {alt_kwh} (grupo de blades más caliente {alt_hot}; en banda {alt_band}). {verdict} No se cambió nada.",
        "Vorausschau über {minutes} am Live-Zwilling (Last und Wetter fest), ab dem jetzigen Zustand: {current} "
        "bräuchte {cur_kwh} Kühlenergie (heißeste Blade-Gruppe {cur_hot}; im Mittel im Band {cur_band}); {other} "
        "{alt_kwh} (heißeste Blade-Gruppe {alt_hot}; im Band {alt_band}). {verdict} Nichts wurde geändert.",
        "Prévision de {minutes} sur le jumeau en direct (charge et météo fixes), depuis l'état actuel : {current} "
        "consommerait {cur_kwh} d'énergie de refroidissement (groupe de lames le plus chaud {cur_hot} ; dans la bande "
        "en moyenne {cur_band}) ; {other} {alt_kwh} (groupe de lames le plus chaud {alt_hot} ; dans la bande {alt_band}). {verdict} Rien n'a "
        "été modifié."),
    "whatif_ctrl.saves": _by_lang("{other} would save {saved} of cooling energy over that time.",
                                  "{other} ahorraría {saved} de energía de refrigeración en ese tiempo.",
                                  "{other} würde in dieser Zeit {saved} Kühlenergie sparen.",
                                  "{other} économiserait {saved} d'énergie de refroidissement sur cette période."),
    "whatif_ctrl.costs": _by_lang("{other} would need {saved} more cooling energy over that time, so the current "
                                  "controller is saving energy against it.",
                                  "{other} necesitaría {saved} más de energía de refrigeración en ese tiempo: el "
                                  "controlador actual ahorra energía frente a él.",
                                  "{other} bräuchte in dieser Zeit {saved} mehr Kühlenergie: der aktuelle Regler "
                                  "spart gegenüber ihm Energie.",
                                  "{other} aurait besoin de {saved} de plus d'énergie de refroidissement sur cette "
                                  "période : le régulateur actuel économise de l'énergie face à lui."),
    "whatif_ctrl.note": _by_lang(" Note: {quote}.", " Nota: {quote}.", " Hinweis: {quote}.", " Note : {quote}."),
    "whatif.pair": _by_lang("{predicted} instead of {baseline}", "{predicted} en lugar de {baseline}",
                            "{predicted} statt {baseline}", "{predicted} au lieu de {baseline}"),
    "whatif.raise": _by_lang("raising", "subir", "anheben", "relever"),
    "whatif.lower": _by_lang("lowering", "bajar", "absenken", "abaisser"),
    "whatif.scope.one": _by_lang("{entity}'s", " {entity_of}", " {entity_of}", " {entity_of}"),
    "whatif.scope.all": _by_lang("the", "", "", ""),
}  # fmt: skip


def phrase(lang: str, key: str, **slots: str) -> str:
    """The catalog's `key` in `lang` with its slots filled (slot values may hold fact placeholders)."""
    return PHRASES[key][lang].format(**slots)


def quantity_label(lang: str, key: str, english: str) -> tuple[str, str, str]:
    """(label, label with its article, gender) of a quantity in `lang`; `english` is plant_data's label."""
    if lang == "en" or key not in LABELS:
        return english, f"the {english}", ""
    with_article = LABELS[key][lang]
    article = with_article[:2] if with_article.startswith("l'") else with_article.split(" ", 1)[0]
    return with_article[len(article):].lstrip(), with_article, _ARTICLES[lang][article]
