"""Where the corpus comes from: one entry per repository, with the licence and artist of
its models as the repository states them (read by hand; see REPORT.md), and rules for
categories. `per` rules (path regex -> licence, artist) override the repository default;
a licence of None means no licence is stated for that file (rejected)."""
import re

PERMISSIVE = ("CC0", "CC-BY", "CC BY", "MIT", "BSD", "Apache", "Zlib", "WTFPL", "Public domain", "Unlicense")
NOT_PERMISSIVE = ("NC", "GPL", "ND", "unknown", "proprietary")


def permissive(lic):
    if any(re.search(rf"\b{re.escape(x)}\b", lic) for x in NOT_PERMISSIVE):
        return False
    return any(lic.upper().startswith(x.upper()) for x in PERMISSIVE)


# category names as in ../shared/rigs/manifest.tsv
CATS = ["humanoid", "humanoid_creature", "quadruped", "bird_flyer", "fish_snake_tail", "insect_spider",
        "robot_prop", "other_creature"]

KEYWORDS = [
    ("robot_prop", r"robot|mech|drone|golem_iron|turret|tank|car|truck|vehicle|machine|android|cyborg|sentry|sam\b|gun|rifle|pistol|door|chest|boat|plane|cart|chair|lamp|crane|arm"),
    ("insect_spider", r"spider|ant\b|ants?_|bee\b|bees?_|wasp|butterfl|moth|beetle|scorpion|insect|fly\b|firefly|dragonfly|mosquito|cricket|grasshopper|ladybug|termite|cockroach|tick|mantis|crab|lobster|snail|worm"),
    ("fish_snake_tail", r"fish|shark|whale|dolphin|snake|serpent|eel|jellyfish|octopus|squid|salmon|trout|tuna|piranha|clown|koi|carp|ray\b|manta|seal\b|orca|tadpole|mosasaur|plesiosaur|dunkleosteus|worm|naga|mermaid|lizard|gecko|salamander|newt|croc|alligator|turtle|tortoise|frog|toad|axolotl|seahorse|angelfish|squid|kraken|leviathan|dragon_water|water_dragon"),
    ("bird_flyer", r"bird|chicken|hen\b|rooster|duck|goose|owl|eagle|hawk|crow|raven|parrot|penguin|pigeon|seagull|gull|flamingo|stork|swan|bat\b|bats?_|dragon|wyvern|pterano|quetzal|griffin|phoenix|turkey|ostrich|peacock|sparrow|robin|vulture|falcon|toucan|cardinal|bluebird|kiwi|dodo|harpy|flying"),
    ("quadruped", r"dog|cat\b|cats?_|wolf|fox|horse|pony|donkey|mule|cow|bull|ox\b|sheep|goat|pig|boar|bear|panda|deer|elk|moose|reindeer|rabbit|bunny|hare|mouse|rat\b|rats?_|hamster|squirrel|badger|hedgehog|raccoon|skunk|otter|beaver|lion|tiger|leopard|cheetah|panther|elephant|mammoth|rhino|hippo|giraffe|zebra|camel|llama|alpaca|kangaroo|dino|raptor|rex|saur|ceratops|smilodon|camel|dire|hound|puppy|kitten|mammal|lamb|calf|yak|bison|buffalo|antelope|gazelle|mole|weasel|ferret|opossum|armadillo|sloth|monkey|ape\b|gorilla|chimp|lemur|wombat|koala|platypus|mount|steed|unicorn|warg|hyena|jackal|coyote|capybara|boar|hog|mink|marten"),
    ("humanoid_creature", r"zombie|skeleton|orc|goblin|ogre|troll|demon|devil|imp\b|ghoul|mummy|vampire|werewolf|yeti|minotaur|golem|gnome|gnorm|dwarf|elf\b|giant|cyclops|lizardman|treeman|ent\b|alien|monster|creature|mutant|undead|lich|wraith|ghost|specter|banshee|oni|yokai|satyr|centaur|slime|blob|cactoro"),
    ("humanoid", r"human|man\b|woman|girl|boy|male|female|character|player|npc|person|people|villager|soldier|knight|warrior|mage|wizard|witch|king|queen|princess|prince|guard|pirate|ninja|samurai|viking|cowboy|worker|farmer|trader|citizen|avatar|adventurer|rogue|barbarian|archer|hunter|clerk|doctor|nurse|police|chef|zombie|mannequin|dummy|body|kid|child|baby|igor|hero|protagonist|survivor|vrm|cesiumman|brainstem|rigged_figure|mixamo|ybot|xbot"),
]


def category(src, path):
    name = path.rsplit("/", 1)[-1].lower()
    for rx, cat in src.get("cat", []):
        if re.search(rx, path, re.I):
            return cat
    for cat, rx in KEYWORDS:
        if re.search(rx, name, re.I):
            return cat
    return src.get("default_cat")


def licence_artist(src, path):
    for rx, lic, artist in src.get("per", []):
        if re.search(rx, path, re.I):
            return lic, artist
    return src.get("licence"), src.get("artist")


def S(repo, licence=None, artist=None, **kw):
    return dict(repo=repo, licence=licence, artist=artist, **kw)


SOURCES = [
    # --- Minetest / Luanti mods ---
    S("Skandarella/animalworld", "MIT", "Liil/Wilhelmine (Skandarella)",
      exclude=r"pelt|trophy|anthil|curtain|ivory|nest|egg|hide|carpet|trap|statue|skull",
      cat=[(r"Clamydosaurus|Iguana|Monitor\.|Crocodile|Frog|Kobra|Goby|Carp|Beluga|Manatee|Leopardseal|seal|Toad|Tortoise|Turtle|Shark|Trout|Pike|Eel|Salamander", "fish_snake_tail"),
           (r"Cockroach|Dragonfly|Divingbeetle|Locust|Crab|Hermitcrab|Lobster|Ant\.|Scorpion|Spider|Snail|Mosquito|Termite|Wasp|Bee\.", "insect_spider"),
           (r"Blackbird|Blackgrouse|Cockatoo|Goose|Bat\.|Owl|Crow|Raven|Gull|Puffin|Kiwi|Ostrich|Emu|Parrot|Pigeon|Robin|Sparrow|Stork|Swan|Vulture|Falcon|Eagle|Duck|Heron|Flamingo|Penguin|Toucan|Hummingbird|Kingfisher|Woodpecker|Yak", None)],
      default_cat="quadruped"),
    S("TheTermos/wildlife", "MIT", "TheTermos", cat=[(r"herbivore", "quadruped")]),
    S("BlockySurvival/mobs_more_animals", None, None, per=[
        (r"mobs_bat/", "CC-BY-SA-3.0", "Defense subgame (mobs_bat)"),
        (r"mobs_(bear|bugslive|deer|giraffe|wolf)/", "MIT", "Krupnov Pavel (mobs_more_animals)"),
        (r"mobs_birds/", "CC-BY-SA-3.0", "Sapier (mobf)"),
        (r"mobs_doomed/", "CC-BY-SA-3.0", "D00Med (dmobs)"),
        (r"mobs_better_rat/", "CC-BY-NC-SA-3.0", "Melkor"),
        (r"mobs_fish/", "CC-BY-SA-3.0", "Sapier (mobf)"),
        (r"mobs_mr_goat/", "unknown", "unknown")], cat=[(r"bug\.x", "insect_spider"), (r"medved|jeraf", "quadruped")]),
    S("ElCeejo/draconis", "MIT", "ElCeejo (Draconis)", exclude=r"egg", cat=[(r"dragon|wyvern", "bird_flyer")]),
    S("D00Med/dmobs", "CC-BY-SA-3.0", "D00Med (dmobs)", exclude=r"egg|_old\.", cat=[(r"nyancat", "quadruped"), (r"whale|water_dragon", "fish_snake_tail")]),
    S("minetest-mobs-mods/dmobs", "CC-BY-SA-3.0", "D00Med (dmobs)", exclude=r"egg|_old\.", cat=[(r"nyancat", "quadruped"), (r"whale|water_dragon", "fish_snake_tail")]),
    S("D00Med/mobs_scifi", "CC-BY-SA-3.0", "D00Med (mobs_scifi)",
      exclude=r"bb8|/r2\.|dalek|cyberman|jabba|metroid|xenomorph|facehugger|irongiant|metalgear|xwing|tank2|core",
      cat=[(r"assaultsuit|mecha|spidermech", "robot_prop")]),
    S("minetest-mirrors/mobs_npc", None, None, per=[(r"mobs_character", "CC-BY-SA-3.0", "MirceaKitsune (Minetest character)")]),
    S("blert2112/mobs_sky", None, None, per=[
        (r"mobs_bat/", "GPL", "Defense subgame (mobs_bat)"),
        (r"mobs_birds/", "CC-BY-SA-3.0", "Sapier (mobf)"),
        (r"mobs_butterfly/", "unknown", "AspireMint")]),
    S("blert2112/mobs_water", None, None, per=[
        (r"mobs_crocs/", "GPL-3.0", "Team NPX"),
        (r"mobs_fish/", "CC-BY-SA-3.0", "Sapier (mobf)"),
        (r"mobs_jellyfish/", "WTFPL", "blert2112"),
        (r"mobs_sharks/", "CC-BY-SA-3.0", "Sapier (mobf)"),
        (r"mobs_turtles/", None, "AspireMint")]),
    S("ElCeejo/paleotest", "GPL-3.0", "ElCeejo (paleotest)"),
    S("runsy/petz", None, "runsy (petz)"),  # README: code GPLv3, textures CC BY-SA 4.0; models: not stated
    S("VoxeLibre/VoxeLibre", "GPL-3.0 (22i models, mobs_mc/LICENSE-media.md)", "22i (VoxeLibre)", include=r"mobs_mc/models/"),
    # --- game-asset packs (CC0) ---
    S("KayKit-Game-Assets/KayKit-Character-Pack-Adventures-1.0", "CC0-1.0", "Kay Lousberg (KayKit)", include=r"Characters/gltf/", default_cat="humanoid"),
    S("KayKit-Game-Assets/KayKit-Character-Pack-Skeletons-1.0", "CC0-1.0", "Kay Lousberg (KayKit)", include=r"Characters/gltf/", cat=[(r"Skeleton_", "humanoid_creature")]),
    S("rcbiscuitsbelfast-prog/viber3d", "CC0-1.0", "Kay Lousberg (KayKit)", include=r"^Assets/KayKit_Adventurers_2.0_FREE/.*/Characters/gltf/", default_cat="humanoid"),
    S("lemonhall/openagentic-sdk-gdscript", "CC0-1.0", "Kenney", include=r"assets/kenney/mini-characters-1/", default_cat="humanoid"),
    S("KenneyNL/Starter-Kit-3D-Platformer", "CC0-1.0", "Kenney", include=r"models/character", default_cat="humanoid"),
    S("KenneyNL/Starter-Kit-FPS", "CC0-1.0", "Kenney", include=r"models/enemy", default_cat="robot_prop"),
    # --- engine demos ---
    S("GDQuest/godot-3d-mannequin", "CC-BY-4.0", "GDQuest", include=r"^godot/assets/3d/mannequiny", default_cat="humanoid"),
    S("vrm-c/vrm-specification", None, "VRM Consortium", include=r"samples/"),
    # --- more Minetest mods ---
    S("BlockMen/cme", "Zlib", "BlockMen (Creatures MOB-Engine)", cat=[(r"ghost", "humanoid_creature"), (r"oerkki", "humanoid_creature")]),
    S("PilzAdam/mobs", "WTFPL", "Pavel_S (PilzAdam mobs)", cat=[(r"dungeon_master|oerkki|sand_monster|stone_monster|tree_monster", "humanoid_creature"), (r"rat", "quadruped")]),
    # --- open-source games ---
    S("redeclipse/actors", "CC-BY-SA-4.0", "Red Eclipse team", include=r"(female/RE_Player_female|male/RE_Player_male|janitor/janitor|janitor/lod\d/|drone/drone|roller/roller|sentry/drone|turret/(base|sphere)/|female/headless/headless-female|/lod\d/)[^/]*\.iqm$",
      exclude=r"roller-|hud", cat=[(r"RE_Player|headless", "humanoid"), (r"janitor|drone|roller|turret|sentry", "robot_prop")]),
    S("UnvanquishedAssets/res-players_src.dpkdir", None, "Viktor Hahn (Unvanquished)", ext=(".blend",), per=[
        (r"human_male/", "CC-BY-SA-3.0", "Viktor Hahn (Unvanquished)")],
      cat=[(r"human_male", "humanoid")]),
    # --- XR ---
    S("GodotVR/godot-xr-tools", "CC0-1.0", "DigitalN8m4r3 (Godot XR Tools hands)", include=r"hands/model/", default_cat="other_creature"),
    # pmndrs/market-assets: Kenney/others, but every model is Draco-compressed (not decodable here)
    S("blert2112/mobs_more_monsters", None, None, per=[
        (r"mobs_senderman/", "WTFPL", "Devyn Collier Johnson (mobs_senderman)"),
        (r"mobs_yeti/", "MIT", "Krupnov Pavel (mobs_more_animals)"),
        (r"mobs_(pumpking|sandworm)/", "GPL-3.0", "mobs_more_monsters"),
        (r"mobs_(creeper|zombie)/", "unknown", "unknown")],
      cat=[(r"sender_man|character", "humanoid_creature")]),
    S("Poikilos/mobs_robot_dystopia", "CC-BY-SA-3.0", "MirceaKitsune/stujones11 derivatives (mobs_robot_dystopia)",
      cat=[(r"tailstheanimatronic", "robot_prop"), (r"zombie|drillers", "humanoid_creature")]),
    # --- round 2 (see REPORT.md) ---
    S("ronrob-lu/mobs_andes", "CC-BY-SA-4.0", "ronrob-lu (mobs_andes)", include=r"^models/", default_cat="quadruped"),
    S("ronrob-lu/mobs_npc_monster", "CC0-1.0", "Kenney", include=r"^models/", default_cat="humanoid"),  # LICENSE.md: assets CC0 by Kenney
    S("0ADMods/A-Mythology-mod-f-or-0-A.D.", "CC-BY-SA-3.0", "A Mythology mod for 0 A.D.", include=r"^art/meshes/skeletal/",
      cat=[(r"centaur|minotaur", "humanoid_creature"), (r"fenrir", "quadruped")]),  # art/LICENSE.txt
    S("BlockySurvival/mobs_bls", "CC-BY-SA-4.0", "Team NPX (NSSM models, mobs_bls)", default_cat="other_creature"),  # LICENSE: models CC BY-SA 4.0
    S("poikilos/mobs_dirt_monster_smooth", "MIT", "poikilos (mobs_dirt_monster_smooth)", default_cat="humanoid_creature"),
    S("N-nec/mobs_zombie", "CC-BY-SA-4.0", "N-nec (mobs_zombie)", cat=[(r"slug", "fish_snake_tail")], default_cat="humanoid_creature"),  # LICENSE-CC-BY-SA for media
    S("gdquest-demos/godot-4-FPS-arms", "CC-BY-4.0", "GDQuest", include=r"fps_arms\.glb$", default_cat="other_creature"),  # readme: art CC-By 4.0
    S("gdquest-demos/godot-demos-2022", "MIT", "GDQuest", include=r"Player3D/astronaut\.gltf$", default_cat="humanoid"),  # LICENSE (MIT) covers the repo
    S("SystemError89/mobs_stoneage", None, None, per=[  # README: Extreme Survival mobs, WTFPL; Mesh by Morn76 / Pavel_S for the mobs_animal ones
        (r"mob_bear|st_cat|mobs_deer2|mobs_medved", "WTFPL", "Extreme Survival mobs (maikerumine)")]),
    S("minenux/minetest-mod-mobs_jam", None, None, per=[(r".", "MIT", "Krupnov Pavel (mobs_more_animals)")]),  # license.txt: all K Pavel models MIT
    S("jordan4ibanez/open_ai", None, None, per=[  # models/models-license.md
        (r"models/(equine2|sheeptest|fishtest)\.b3d$", "CC-BY-SA-3.0", "FreeLikeGNU (open_ai models)")],
      cat=[(r"fishtest", "fish_snake_tail"), (r"equine|sheep", "quadruped")]),
    S("AiTechEye/aliveai", "CC0-1.0", "AiTechEye (aliveai)", cat=[(r"spider", "robot_prop")]),  # README: code LGPL-2.1, media CC0
    S("minetest-LOTR/Lord-of-the-Test", None, None, include=r"^mods/lottmobs/models/", per=[  # mods/lottmobs/license.txt, media authors
        (r"/(ent_model|mobs_bunny|ringwraith_model|shirepony_model|shireponyh1_model|spider_model|chicken_model)\.", "CC-BY-SA-3.0", "AspireMint (lottmobs)"),
        (r"/(mobs_rat|mobs_sheep|mobs_sheep_shaved|troll_model)\.", "WTFPL", "Pavel_S (PilzAdam mobs)"),
        (r"/balrog_model\.", "CC-BY-SA-3.0", "STHGOM (lottmobs balrog)"),
        (r"/(mobs_pumba|horse_model|horseh1_model)\.", "MIT", "Krupnov Pavel (mobs_more_animals)"),
        (r"/warg(_mount)?\.", "CC-BY-SA-3.0", "fishyWET (lottmobs)")],
      cat=[(r"ent_model|troll|balrog|ringwraith", "humanoid_creature"), (r"pony|warg|pumba", "quadruped")]),
    S("minetest-mods-camp/witches", "CC-BY-SA-3.0", "FreeLikeGNU (open_ai models)", include=r"models/witches_(witch|sheep)\.b3d$",  # README: media licences
      cat=[(r"witch\.b3d", "humanoid"), (r"sheep", "quadruped")]),
]
